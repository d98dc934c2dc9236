"""openpi's policy protocol (Physical Intelligence): a WebSocket, msgpack, numpy arrays as plain maps.

pi0 / pi0.5 servers (``scripts/serve_policy.py`` in openpi), starVLA and
IsaacLab-Arena speak it; ``embagents serve-policy`` serves our policies with it
(:mod:`embagents.models.openpi_server`). The protocol:

- one client per connection; on connect the server sends its metadata (a map);
- then each binary message is an observation map, answered by an action map
  holding ``actions`` (T, action_dim) and ``server_timing``
  (``infer_ms``, and ``prev_total_ms`` from the second answer on);
- an error is a text frame with the server's traceback, then close code 1011;
- numpy arrays are maps ``{b"__ndarray__": True, b"data", b"dtype", b"shape"}``,
  numpy scalars ``{b"__npgeneric__": True, b"data", b"dtype"}`` (keys as msgpack
  bin, as ``openpi_client.msgpack_numpy`` writes them); object, void and complex
  dtypes are refused. Nothing is ever unpickled;
- an optional ``Authorization: Api-Key KEY`` header; ``GET /healthz`` answers 200.

:class:`OpenPIPolicyClient` is a :class:`~embagents.models.policy.PolicyClient`:
our observation keys (``observation.state``, ``observation.images.<camera>``,
the task) go out under the server's keys (``key_map``), the answer's
``actions`` come back as a float32 ``(actions_per_chunk, n_joints)`` chunk.

Example::

    >>> unpackb(packb({"state": np.arange(3, dtype=np.float32)}))["state"]
    array([0., 1., 2.], dtype=float32)
    >>> default_key("observation.images.front")
    'observation/images/front'
    >>> client = OpenPIPolicyClient("ws://127.0.0.1:8000", key_map={"observation.state": "observation/state"})
    >>> client.infer({"observation.state": np.zeros(7, np.float32)}, "pick", 0.5).shape  # doctest: +SKIP
    (10, 7)
"""

from __future__ import annotations

import inspect
import logging
import time
from collections.abc import Mapping, Sequence
from typing import Any
from urllib.parse import urlsplit

import msgpack
import numpy as np

from embagents.models.lerobot import PolicyError, PolicyUnavailable, check_chunk
from embagents.models.policy import PolicyLate
from embagents.models.protocol import BadRequest

log = logging.getLogger("embagents.models.openpi")

__all__ = ["OpenPIPolicyClient", "default_key", "normalize_key", "packb", "unpackb"]

#: dtype kinds that travel: bool, ints, floats, and fixed-width strings (never object, void or complex).
KINDS = "biufSU"
#: The largest message either side takes (a few camera images and a chunk fit many times over).
MAX_MESSAGE_BYTES = 64 * 1024 * 1024
_INSTALL_HINT = "pip install 'embagents[vla]' (websockets)"


def _refuse(dtype: np.dtype) -> None:
    if dtype.kind not in KINDS:
        raise ValueError(f"arrays of dtype {dtype} are refused (openpi's protocol carries bool, integer, float and "
                         "string arrays; object, void and complex ones never)")


def _pack(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        _refuse(obj.dtype)
        return {b"__ndarray__": True, b"data": obj.tobytes(), b"dtype": obj.dtype.str, b"shape": list(obj.shape)}
    if isinstance(obj, np.generic):
        _refuse(obj.dtype)
        return {b"__npgeneric__": True, b"data": obj.item(), b"dtype": obj.dtype.str}
    raise TypeError(f"cannot send a {type(obj).__name__} over openpi's protocol (maps, lists, numbers, text, arrays)")


def _field(obj: Mapping[Any, Any], name: str) -> Any:
    for key in (name.encode(), name):
        if key in obj:
            return obj[key]
    raise ValueError(f"an array map lacks {name!r}")


def _unpack(obj: dict[Any, Any]) -> Any:
    if obj.get(b"__ndarray__") is True or obj.get("__ndarray__") is True:
        dtype = np.dtype(_field(obj, "dtype"))
        _refuse(dtype)
        shape, data = _field(obj, "shape"), _field(obj, "data")
        if not isinstance(data, bytes) or not isinstance(shape, list) or not all(
                isinstance(d, int) and d >= 0 for d in shape):
            raise ValueError("an array map needs bytes data and a shape of non-negative integers")
        if int(np.prod(shape, dtype=np.int64)) * dtype.itemsize != len(data):
            raise ValueError(f"an array of shape {tuple(shape)} and dtype {dtype} needs "
                             f"{int(np.prod(shape)) * dtype.itemsize} bytes, got {len(data)}")
        return np.frombuffer(data, dtype).reshape(shape)
    if obj.get(b"__npgeneric__") is True or obj.get("__npgeneric__") is True:
        dtype = np.dtype(_field(obj, "dtype"))
        _refuse(dtype)
        return dtype.type(_field(obj, "data"))
    return obj


def packb(value: Any) -> bytes:
    """``value`` (maps, lists, numbers, text, numpy arrays and scalars) as openpi's msgpack bytes."""
    return msgpack.packb(value, default=_pack, use_bin_type=True)


def unpackb(data: bytes) -> Any:
    """openpi's msgpack bytes as Python values with numpy arrays (read-only); ``ValueError`` for anything else.

    >>> unpackb(packb({"x": np.zeros(2, complex)}))
    Traceback (most recent call last):
    ...
    ValueError: arrays of dtype complex128 are refused (openpi's protocol carries bool, integer, float and string arrays; object, void and complex ones never)
    """
    try:
        return msgpack.unpackb(data, object_hook=_unpack, raw=False)
    except ValueError:
        raise
    except Exception as exc:  # msgpack's own errors, a bad dtype string...
        raise ValueError(f"not an openpi msgpack message ({type(exc).__name__}: {exc})") from None


def normalize_key(key: str) -> str:
    """A key as compared between the two sides: openpi's ``/`` separators as our ``.``.

    >>> normalize_key("observation/state")
    'observation.state'
    """
    return key.replace("/", ".")


def default_key(key: str) -> str:
    """The server key an observation key goes out as when no ``key_map`` names it (openpi's ``/`` style)."""
    return key.replace(".", "/")


def _loopback(host: str) -> bool:
    from embagents.models.lerobot import is_loopback  # lazy: a cycle

    return is_loopback(f"[{host}]:0" if ":" in host else f"{host}:0")


class OpenPIPolicyClient:
    """A :class:`~embagents.models.policy.PolicyClient` for a policy server speaking openpi's WebSocket protocol.

    - ``url``: ``ws://host:port`` or ``wss://host:port`` (TLS; ``tls_ca``: a PEM file to trust
      besides the system's, for a self-signed server certificate);
    - ``api_key``: sent as ``Authorization: Api-Key KEY`` (beyond loopback, over ``wss://`` only);
    - ``key_map``: our observation keys (and ``"task"``) -> the server's keys; with it, only
      those keys are sent. Without it every key goes out ``/``-separated
      (``observation.state`` -> ``observation/state``) and the task as ``prompt_key``;
    - ``action_key``: the answer's key holding the chunk; ``actions_per_chunk``: the chunk
      length required (None: the metadata's ``actions_per_chunk`` when it says, else any);
      ``action_dims``: use the first N columns (pi0 pads its actions to 32 dims);
    - ``required_metadata``: keys the server's metadata must hold (named when missing);
    - ``retry_after_error_s``: after the server failed (a traceback, close 1011), the same
      error is raised without asking again for this long: one traceback, not a loop of them.

    After each answer ``server_timing`` holds the server's ``infer_ms`` / ``prev_total_ms``
    and ``timing`` adds ``roundtrip_ms`` (observation sent -> chunk received). A server that
    went away (restarted) raises :class:`PolicyUnavailable`; the next call reconnects.
    """

    def __init__(self, url: str, *, api_key: str | None = None, key_map: Mapping[str, str] | None = None,
                 prompt_key: str | None = "prompt", action_key: str = "actions", actions_per_chunk: int | None = None,
                 action_dims: int | None = None, required_metadata: Sequence[str] = (), name: str = "openpi",
                 tls_ca: str | None = None, connect_timeout_s: float = 5.0, retry_after_error_s: float = 2.0) -> None:
        parts = urlsplit(url)
        if parts.scheme not in ("ws", "wss") or not parts.hostname:
            raise ValueError(f"openpi server url {url!r}: expected ws://HOST:PORT or wss://HOST:PORT")
        if actions_per_chunk is not None and int(actions_per_chunk) < 1:
            raise ValueError(f"actions_per_chunk must be >= 1, got {actions_per_chunk!r}")
        self.url, self.name = url, name
        self.api_key = api_key
        self.key_map = dict(key_map) if key_map is not None else None
        self.prompt_key, self.action_key = prompt_key, action_key
        self.actions_per_chunk = int(actions_per_chunk) if actions_per_chunk is not None else None
        self.action_dims = int(action_dims) if action_dims is not None else None
        self.required_metadata = list(required_metadata)
        self.connect_timeout_s, self.retry_after_error_s = float(connect_timeout_s), float(retry_after_error_s)
        self.tls_ca = tls_ca
        self.metadata: dict[str, Any] | None = None
        self.server_timing: dict[str, float] = {}
        self.timing: dict[str, float] = {}
        self.connects = 0
        self._ws: Any = None
        self._pending = 0  # answers still owed to requests that timed out
        self._failed: tuple[float, str] | None = None  # (retry after, text) of the server's last error
        if parts.scheme == "ws" and not _loopback(parts.hostname):
            log.warning("%s: %s is plaintext beyond this machine: anyone on the way reads the observations%s; use "
                        "wss:// (serve-policy --tls-cert/--tls-key) or a tunnel you trust", name, url,
                        " and the API key" if api_key else "")

    def __repr__(self) -> str:
        return f"OpenPIPolicyClient({self.url!r})"

    # -- connection ---------------------------------------------------------------------------------------------
    def connect(self, timeout_s: float | None = None) -> dict[str, Any]:
        """Open the connection (if not open) and read the server's metadata; returns it."""
        if self._ws is not None and self.metadata is not None:
            return self.metadata
        try:
            from websockets.exceptions import InvalidHandshake, InvalidStatus, InvalidURI
            from websockets.sync.client import connect
        except ImportError as exc:
            raise ModuleNotFoundError(f"the openpi client needs websockets: {_INSTALL_HINT}") from exc
        timeout = self.connect_timeout_s if timeout_s is None else max(0.01, min(timeout_s, self.connect_timeout_s))
        headers = {"Authorization": f"Api-Key {self.api_key}"} if self.api_key else None
        ssl_ctx = None
        if self.url.startswith("wss:"):
            import ssl

            ssl_ctx = ssl.create_default_context(cafile=self.tls_ca) if self.tls_ca else ssl.create_default_context()
        # websockets >= 17.1 wants legacy=True for a connection held outside a with block (ours lives on)
        legacy: dict[str, Any] = {"legacy": True} if "legacy" in inspect.signature(connect).parameters else {}
        try:
            ws = connect(self.url, additional_headers=headers, compression=None, max_size=MAX_MESSAGE_BYTES,
                         open_timeout=timeout, ssl=ssl_ctx, proxy=None, ping_interval=None, **legacy)
        except InvalidStatus as exc:
            status = exc.response.status_code
            body = exc.response.body.decode(errors="replace").strip() if exc.response.body else ""
            if status in (401, 403):
                raise PolicyError(f"policy server {self.url} refused this client ({status}: {body}); pass the "
                                  "API key it was started with (api_key=)") from None
            raise PolicyUnavailable(f"policy server {self.url} refused the connection ({status}: {body})") from None
        except (OSError, TimeoutError, InvalidHandshake, InvalidURI) as exc:
            raise PolicyUnavailable(f"policy server {self.url} is not reachable ({type(exc).__name__}: {exc}); is it "
                                    "running? (embagents serve-policy POLICY --bind ws://HOST:PORT, or openpi's "
                                    "scripts/serve_policy.py); the next call reconnects") from None
        try:
            first = ws.recv(timeout=timeout)
            if isinstance(first, str):
                raise PolicyError(f"policy server {self.url} failed on connect:\n{first}")
            metadata = unpackb(first)
        except TimeoutError:
            ws.close()
            raise PolicyUnavailable(f"policy server {self.url} sent no metadata within {timeout:.3g} s") from None
        except ValueError as exc:
            ws.close()
            raise PolicyError(f"policy server {self.url} sent unreadable metadata: {exc}") from None
        except Exception:
            ws.close()
            raise
        if not isinstance(metadata, dict):
            ws.close()
            raise PolicyError(f"policy server {self.url} sent metadata that is not a map: {type(metadata).__name__}")
        missing = [k for k in self.required_metadata if k not in metadata]
        if missing:
            ws.close()
            raise PolicyError(f"policy server {self.url}'s metadata lacks {', '.join(map(repr, missing))}, which this "
                              f"client needs (required_metadata); it has: {', '.join(map(str, metadata)) or 'nothing'}")
        self._ws, self.metadata, self._pending = ws, metadata, 0
        self.connects += 1
        log.info("%s: connected to %s (metadata: %s)", self.name, self.url, ", ".join(map(str, metadata)) or "none")
        return metadata

    def _drop(self) -> None:
        ws, self._ws, self.metadata = self._ws, None, None
        if ws is not None:
            ws.close()

    # -- the policy ---------------------------------------------------------------------------------------------
    def request(self, observation: Mapping[str, np.ndarray], task: str) -> dict[str, Any]:
        """The map sent to the server for ``observation`` and ``task`` (keys mapped, see the class docs)."""
        out: dict[str, Any] = {}
        if self.key_map is None:
            out.update({default_key(k): np.asarray(v) for k, v in observation.items()})
            if self.prompt_key:
                out[self.prompt_key] = task
            return out
        for ours, theirs in self.key_map.items():
            if ours == "task":
                out[theirs] = task
            elif ours in observation:
                out[theirs] = np.asarray(observation[ours])
            else:
                raise BadRequest(f"key_map maps {ours!r} to {theirs!r}, but the observation has no {ours!r} "
                                 f"(it has {', '.join(observation)})")
        if self.prompt_key and "task" not in self.key_map:
            out[self.prompt_key] = task
        return out

    def _check_keys(self, sent: Mapping[str, Any]) -> None:
        wanted = (self.metadata or {}).get("observation_keys")
        if not isinstance(wanted, list):
            return
        have = {normalize_key(k) for k in sent}
        missing = [k for k in wanted if isinstance(k, str) and normalize_key(k) not in have]
        if missing:
            raise BadRequest(f"policy server {self.url} needs observation keys {missing} (its metadata's "
                             f"observation_keys) that this client does not send (it sends {sorted(sent)}); "
                             "map them with key_map={our_key: their_key}")

    def infer(self, observation: Mapping[str, np.ndarray], task: str, timeout_s: float) -> np.ndarray:
        """The chunk for ``observation``: float32 ``(actions_per_chunk, n_joints)``.

        Raises :class:`PolicyUnavailable` (not reachable, or it went away: the next call
        reconnects), :class:`PolicyLate` (no answer within ``timeout_s``; its answer is
        skipped when it comes), :class:`PolicyError` (the server failed: its traceback;
        or a chunk of the wrong shape), :class:`BadRequest` (keys the server needs are not sent).
        """
        from websockets.exceptions import ConnectionClosed

        start = time.monotonic()
        deadline = start + float(timeout_s)
        if self._failed is not None:
            retry_at, text = self._failed
            if start < retry_at:
                raise PolicyError(text)
            self._failed = None
        self.connect(timeout_s)
        payload = self.request(observation, task)
        self._check_keys(payload)
        try:
            data = packb(payload)
        except (TypeError, ValueError) as exc:
            raise BadRequest(f"observation for {self.url} cannot be sent: {exc}") from None
        try:
            while self._pending:  # answers to requests that timed out: skipped, they are old
                self._recv(deadline, timeout_s)
                self._pending -= 1
            sent = time.monotonic()
            self._ws.send(data)
            answer = self._recv(deadline, timeout_s)
        except ConnectionClosed as exc:
            self._drop()
            raise PolicyUnavailable(f"policy server {self.url} closed the connection ({exc}); it may be restarting; "
                                    "the next call reconnects") from None
        except OSError as exc:
            self._drop()
            raise PolicyUnavailable(f"policy server {self.url} went away ({exc}); the next call reconnects") from None
        received = time.monotonic()
        chunk = self._chunk(answer, observation)
        timing = answer.get("server_timing")
        self.server_timing = {str(k): float(v) for k, v in timing.items() if isinstance(v, int | float)} \
            if isinstance(timing, dict) else {}
        self.timing = {**self.server_timing, "roundtrip_ms": round((received - sent) * 1000.0, 3)}
        return chunk

    def _recv(self, deadline: float, timeout_s: float) -> dict[str, Any]:
        left = deadline - time.monotonic()
        try:
            if left <= 0:
                raise TimeoutError
            message = self._ws.recv(timeout=left)
        except TimeoutError:
            self._pending += 1
            raise PolicyLate(f"policy server {self.url} gave no actions within {timeout_s:.3g} s; motion should "
                             "stop until the next chunk") from None
        if isinstance(message, str):  # openpi: an error is the traceback as text, then close 1011
            text = f"policy server {self.url} failed:\n{message.strip()}"
            self._drop()
            self._failed = (time.monotonic() + self.retry_after_error_s, text)
            raise PolicyError(text)
        try:
            answer = unpackb(message)
        except ValueError as exc:
            raise PolicyError(f"policy server {self.url} sent an unreadable answer: {exc}") from None
        if not isinstance(answer, dict):
            raise PolicyError(f"policy server {self.url} answered a {type(answer).__name__}, not an action map")
        return answer

    def _chunk(self, answer: Mapping[str, Any], observation: Mapping[str, np.ndarray]) -> np.ndarray:
        actions = answer.get(self.action_key)
        if not isinstance(actions, np.ndarray):
            raise PolicyError(f"policy server {self.url} answered no {self.action_key!r} array (keys: "
                              f"{', '.join(map(str, answer))}); set action_key= to the key holding the chunk")
        if self.action_dims is not None and actions.ndim == 2:
            actions = actions[:, : self.action_dims]
        length = self.actions_per_chunk
        if length is None and isinstance((self.metadata or {}).get("actions_per_chunk"), int):
            length = int((self.metadata or {})["actions_per_chunk"])
        return check_chunk(actions, observation, length, f"policy server {self.url}")

    def close(self) -> None:
        """Close the connection (a later call opens a new one)."""
        self._drop()
