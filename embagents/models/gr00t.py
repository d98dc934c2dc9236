"""NVIDIA Isaac GR00T's policy server protocol (``gr00t/policy/server_client.py``), as a client.

GR00T serves its policies over ZeroMQ REQ/REP: each request is a msgpack map
``{"endpoint": "get_action", "data": {observation}, "api_token": TOKEN}``
(``api_token`` only when the server was started with one; other endpoints:
``get_modality_config``, ``ping``), each answer a msgpack map: the actions
(``{"action.<part>": (T, D)}``) or ``{"error": text}``. numpy arrays travel as
``{"__ndarray_class__": True, "as_npy": <np.save bytes>}``, read back here with
``np.load(..., allow_pickle=False)``: an object array (a pickle inside) is refused, never loaded.

Observations follow GR00T's naming: the state vector is split into its body
parts (``state_keys``, e.g. ``{"state.single_arm": 5, "state.gripper": 1}``),
each camera is ``video.<camera>`` and the task is
``annotation.human.task_description``; arrays get GR00T's leading time
dimension of 1. The chunk is the ``action_keys`` parts side by side, as a
float32 ``(T, n_joints)``.

A REQ socket whose answer never came is stuck (it may not send again), so a
timeout closes it and opens a fresh one: the next call goes out at once.

Example::

    >>> client = Gr00tPolicyClient("tcp://127.0.0.1:5555", state_keys={"state.single_arm": 5, "state.gripper": 1},
    ...                            action_keys=["action.single_arm", "action.gripper"])
    >>> decode(encode({"x": np.arange(3)}))["x"]
    array([0, 1, 2])
    >>> client.infer({"observation.state": np.zeros(6, np.float32)}, "pick", 0.5).shape  # doctest: +SKIP
    (16, 6)
"""

from __future__ import annotations

import io
import json
import logging
from collections.abc import Mapping, Sequence
from typing import Any
from urllib.parse import urlsplit

import msgpack
import numpy as np
import zmq

from embagents.models.lerobot import PolicyError, PolicyUnavailable, check_chunk
from embagents.models.policy import STATE_KEY, PolicyLate
from embagents.models.protocol import BadRequest

log = logging.getLogger("embagents.models.gr00t")

__all__ = ["Gr00tPolicyClient", "decode", "encode"]

#: dtype kinds that travel (never object, void or complex).
KINDS = "biufSU"
TASK_KEY = "annotation.human.task_description"


def _encode(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind not in KINDS:
            raise ValueError(f"arrays of dtype {obj.dtype} are refused (numbers, bools and strings only)")
        out = io.BytesIO()
        np.save(out, obj, allow_pickle=False)
        return {"__ndarray_class__": True, "as_npy": out.getvalue()}
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"cannot send a {type(obj).__name__} to a GR00T server")


def _decode(obj: dict[Any, Any]) -> Any:
    if obj.get("__ndarray_class__") is True:
        data = obj.get("as_npy")
        if not isinstance(data, bytes):
            raise ValueError("an __ndarray_class__ map without as_npy bytes")
        array = np.load(io.BytesIO(data), allow_pickle=False)  # an object array raises: no pickle is ever loaded
        if array.dtype.kind not in KINDS:
            raise ValueError(f"arrays of dtype {array.dtype} are refused (numbers, bools and strings only)")
        return array
    if obj.get("__ModalityConfig_class__") is True and isinstance(obj.get("as_json"), str):
        return json.loads(obj["as_json"])  # a plain map: GR00T's pydantic class is not ours to build
    return obj


def encode(value: Mapping[str, Any]) -> bytes:
    """A request (or answer) in GR00T's msgpack encoding."""
    return msgpack.packb(value, default=_encode, use_bin_type=True)


def decode(data: bytes) -> Any:
    """GR00T's msgpack bytes as Python values with numpy arrays; ``ValueError`` for anything else."""
    try:
        return msgpack.unpackb(data, object_hook=_decode, raw=False)
    except ValueError as exc:
        raise ValueError(f"not a GR00T message: {exc}") from None
    except Exception as exc:
        raise ValueError(f"not a GR00T message ({type(exc).__name__}: {exc})") from None


class Gr00tPolicyClient:
    """A :class:`~embagents.models.policy.PolicyClient` for a GR00T policy server (see the module docstring).

    - ``endpoint``: ``tcp://host:port`` (GR00T's default port is 5555);
    - ``api_token``: sent in each request when the server was started with one;
    - ``state_keys``: GR00T's state parts and their sizes, in the order of our state vector
      (default: the whole vector as ``state.joints``);
    - ``camera_keys``: our camera names -> GR00T's video keys (default ``video.<camera>``);
    - ``action_keys``: the action parts that make up the chunk, in joint order (default: every
      ``action.*`` key of the answer, in its order); ``actions_per_chunk``: the length required
      (None: any);
    - ``time_dim``: add GR00T's leading time dimension of 1 to each array (its policies want it).

    Raises :class:`PolicyLate` when no answer comes within the call's timeout (the socket is
    reset: the next call goes out at once), :class:`PolicyError` for the server's ``error``
    (a wrong token included) or a chunk of the wrong shape.
    """

    def __init__(self, endpoint: str, *, api_token: str | None = None, state_keys: Mapping[str, int] | None = None,
                 camera_keys: Mapping[str, str] | None = None, action_keys: Sequence[str] | None = None,
                 actions_per_chunk: int | None = None, time_dim: bool = True, name: str = "gr00t") -> None:
        parts = urlsplit(endpoint)
        if parts.scheme != "tcp" or not parts.hostname:
            raise ValueError(f"GR00T endpoint {endpoint!r}: expected tcp://HOST:PORT (e.g. tcp://127.0.0.1:5555)")
        self.endpoint, self.name, self.api_token = endpoint, name, api_token
        self.state_keys = dict(state_keys) if state_keys is not None else None
        self.camera_keys = dict(camera_keys or {})
        self.action_keys = list(action_keys) if action_keys is not None else None
        self.actions_per_chunk = int(actions_per_chunk) if actions_per_chunk is not None else None
        self.time_dim = bool(time_dim)
        self.resets = 0
        self._sock: zmq.Socket | None = None
        from embagents.models.lerobot import is_loopback  # lazy: a cycle

        if not is_loopback(parts.netloc):
            log.warning("%s: GR00T's protocol to %s is plaintext ZeroMQ%s: anyone on that network can read the "
                        "observations; keep the server on this machine or reach it through a tunnel you trust "
                        "(ssh -L, WireGuard)", name, endpoint, " and the token travels in the clear" if api_token else "")

    def __repr__(self) -> str:
        return f"Gr00tPolicyClient({self.endpoint!r})"

    def _socket(self) -> zmq.Socket:
        if self._sock is None:
            sock: Any = zmq.Context.instance().socket(zmq.REQ)
            sock.setsockopt(zmq.LINGER, 0)
            sock.connect(self.endpoint)
            self._sock = sock
        return self._sock

    def _reset(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close(linger=0)

    def call(self, endpoint: str, data: Any = None, timeout_s: float = 5.0) -> Any:
        """One request to GR00T's ``endpoint`` (with ``data`` when given); its answer, decoded."""
        request: dict[str, Any] = {"endpoint": endpoint}
        if data is not None:
            request["data"] = data
        if self.api_token:
            request["api_token"] = self.api_token
        try:
            payload = encode(request)
        except (TypeError, ValueError) as exc:
            raise BadRequest(f"observation for {self.endpoint} cannot be sent: {exc}") from None
        sock = self._socket()
        sock.send(payload)
        if not sock.poll(max(1, int(timeout_s * 1000)), zmq.POLLIN):
            self._reset()  # the REQ socket would refuse to send again until this answer came
            self.resets += 1
            raise PolicyLate(f"GR00T server {self.endpoint} gave no answer to {endpoint!r} within {timeout_s:.3g} s "
                             "(is it running? python scripts/inference_service.py --server --port PORT); the socket "
                             "was reset, the next call asks again")
        try:
            answer = decode(sock.recv())
        except ValueError as exc:
            raise PolicyError(f"GR00T server {self.endpoint} sent an unreadable answer: {exc}") from None
        if isinstance(answer, dict) and "error" in answer:
            hint = "; pass the server's token (api_token=)" if "token" in str(answer["error"]).lower() else ""
            raise PolicyError(f"GR00T server {self.endpoint} failed: {answer['error']}{hint}")
        return answer

    def ping(self, timeout_s: float = 2.0) -> bool:
        """Whether the server answers its ``ping`` endpoint in time."""
        try:
            self.call("ping", timeout_s=timeout_s)
        except (PolicyLate, PolicyError, PolicyUnavailable):
            return False
        return True

    def modality_config(self, timeout_s: float = 5.0) -> Any:
        """The server's ``get_modality_config`` answer (its keys, horizons and shapes)."""
        return self.call("get_modality_config", timeout_s=timeout_s)

    def request(self, observation: Mapping[str, np.ndarray], task: str) -> dict[str, Any]:
        """The observation map GR00T gets (see the class docstring)."""
        out: dict[str, Any] = {}
        add = (lambda a: a[None]) if self.time_dim else (lambda a: a)
        state = np.asarray(observation[STATE_KEY]) if STATE_KEY in observation else None
        if state is not None:
            parts = self.state_keys or {"state.joints": int(state.size)}
            if sum(parts.values()) != state.size:
                raise BadRequest(f"state_keys {parts} add up to {sum(parts.values())} joints, the state has "
                                 f"{state.size}; list every part with its size")
            at = 0
            for key, size in parts.items():
                out[key] = add(np.ascontiguousarray(state[at:at + size]))
                at += size
        prefix = "observation.images."
        for key, value in observation.items():
            if key.startswith(prefix):
                camera = key[len(prefix):]
                out[self.camera_keys.get(camera, f"video.{camera}")] = add(np.asarray(value))
        out[TASK_KEY] = [task]
        return out

    def infer(self, observation: Mapping[str, np.ndarray], task: str, timeout_s: float) -> np.ndarray:
        """The chunk for ``observation``: float32 ``(T, n_joints)`` (see the class docstring for errors)."""
        answer = self.call("get_action", self.request(observation, task), timeout_s)
        if isinstance(answer, list) and answer and isinstance(answer[0], dict):
            answer = answer[0]  # (action, info) as newer servers answer
        if not isinstance(answer, dict):
            raise PolicyError(f"GR00T server {self.endpoint} answered a {type(answer).__name__}, not an action map")
        keys = self.action_keys or [k for k in answer if isinstance(k, str) and k.startswith("action.")]
        missing = [k for k in keys if not isinstance(answer.get(k), np.ndarray)]
        if not keys or missing:
            raise PolicyError(f"GR00T server {self.endpoint} answered no {missing or 'action.*'} arrays (keys: "
                              f"{', '.join(map(str, answer))}); set action_keys= to the parts that make the chunk")
        parts = []
        for k in keys:
            a = answer[k]
            a = a[0] if a.ndim == 3 and a.shape[0] == 1 else a  # a batch of one
            parts.append(a[:, None] if a.ndim == 1 else a)
        lengths = {p.shape[0] for p in parts}
        if len(lengths) != 1 or any(p.ndim != 2 for p in parts):
            raise PolicyError(f"GR00T server {self.endpoint} answered parts of shapes "
                              f"{[tuple(p.shape) for p in parts]} for {keys}: not one chunk")
        return check_chunk(np.concatenate(parts, axis=1), observation, self.actions_per_chunk,
                           f"GR00T server {self.endpoint} (from {', '.join(keys)})")

    def close(self) -> None:
        """Close the socket (a later call opens a new one)."""
        self._reset()
