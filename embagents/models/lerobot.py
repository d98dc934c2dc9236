"""A LeRobot policy server, reached over its async-inference gRPC protocol (:class:`LeRobotPolicyClient`).

LeRobot serves policies (ACT, SmolVLA, pi0...) with
``python -m lerobot.async_inference.policy_server``; robots reach it over
gRPC, service ``transport.AsyncInference``:

- ``Ready(Empty) -> Empty``: a new client (the server forgets the previous one);
- ``SendPolicyInstructions(PolicySetup{data}) -> Empty``: which policy, its
  features, actions per chunk, device;
- ``SendObservations(stream Observation{transfer_state, data}) -> Empty``: one
  observation, in chunks of at most 2 MB (BEGIN / MIDDLE / END; a single chunk is END);
- ``GetActions(Empty) -> Actions{data}``: the chunk for the latest observation
  (empty data when none came in time).

The messages are built here from their field numbers (:func:`messages`), no
generated code. **Payloads**: LeRobot pickles them (``RemotePolicyConfig``,
``TimedObservation`` and a list of ``TimedAction`` with torch tensors). A
pickle can run code when it is loaded, and nothing of embagents pickles
across processes: this client's payloads are msgpack with numeric numpy
arrays, what :mod:`embagents.models.lerobot_server` speaks (it serves an ONNX
policy over the same service). LeRobot's own server, which reads pickles
only, answers the setup with an error that says so.

Errors: a server that is down raises :class:`PolicyUnavailable` (the next
call reconnects and says hello again), one that answers too late
:class:`~embagents.models.policy.PolicyLate`, a chunk of the wrong shape
:class:`PolicyError` naming expected and actual.

Example::

    >>> client = LeRobotPolicyClient("127.0.0.1:8080", actions_per_chunk=10)
    >>> client.infer({"observation.state": np.zeros(7, np.float32)}, "reach the cup", 0.5).shape  # doctest: +SKIP
    (10, 7)
"""

from __future__ import annotations

import functools
import ipaddress
import logging
import os
import time
from collections.abc import Iterator, Mapping
from typing import Any

import msgpack
import numpy as np

from embagents.models.policy import STATE_KEY, PolicyLate
from embagents.models.protocol import BadRequest, ModelError, ModelUnavailable

log = logging.getLogger("embagents.models.lerobot")

__all__ = [
    "CHUNK_BYTES",
    "LeRobotPolicyClient",
    "PolicyError",
    "check_chunk",
    "PolicyUnavailable",
    "decode_payload",
    "encode_payload",
    "messages",
    "method",
]

#: LeRobot's chunk size for streamed observations (and its 4 MB message limit above it).
CHUNK_BYTES = 2 * 1024 * 1024
SERVICE = "transport.AsyncInference"
#: Marks our msgpack payloads, so either side tells them from pickles at once.
FORMAT = "embagents-msgpack-1"
_INSTALL_HINT = "pip install 'embagents[vla]' (grpcio, protobuf)"


class PolicyUnavailable(ModelUnavailable):
    """The policy server cannot be reached (down, restarting, wrong address)."""


class PolicyError(ModelError):
    """The policy server answered with an error, or with a chunk of the wrong shape."""


@functools.lru_cache(maxsize=1)
def messages() -> dict[str, Any]:
    """The protocol's message classes (``Empty``, ``Observation``, ``Actions``, ``PolicySetup``) and ``TransferState``.

    Built from their field numbers into a pool of their own (no clash with LeRobot's
    generated module when both are imported).

    >>> m = messages()
    >>> m["Observation"](transfer_state=m["TRANSFER_END"], data=b"x").SerializeToString()
    b'\\x08\\x03\\x12\\x01x'
    """
    try:
        from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
    except ImportError as exc:
        raise ModuleNotFoundError(f"the LeRobot client needs protobuf: {_INSTALL_HINT}") from exc
    F = descriptor_pb2.FieldDescriptorProto
    proto = descriptor_pb2.FileDescriptorProto(name="embagents/lerobot_transport.proto", package="transport",
                                               syntax="proto3")
    enum = proto.enum_type.add(name="TransferState")
    for number, name in enumerate(("TRANSFER_UNKNOWN", "TRANSFER_BEGIN", "TRANSFER_MIDDLE", "TRANSFER_END")):
        enum.value.add(name=name, number=number)
    proto.message_type.add(name="Empty")
    obs = proto.message_type.add(name="Observation")
    obs.field.add(name="transfer_state", number=1, type=F.TYPE_ENUM, type_name=".transport.TransferState",
                  label=F.LABEL_OPTIONAL)
    obs.field.add(name="data", number=2, type=F.TYPE_BYTES, label=F.LABEL_OPTIONAL)
    for name in ("Actions", "PolicySetup"):
        proto.message_type.add(name=name).field.add(name="data", number=1, type=F.TYPE_BYTES, label=F.LABEL_OPTIONAL)
    pool = descriptor_pool.DescriptorPool()
    pool.Add(proto)
    out: dict[str, Any] = {name: message_factory.GetMessageClass(pool.FindMessageTypeByName(f"transport.{name}"))
                           for name in ("Empty", "Observation", "Actions", "PolicySetup")}
    out.update({v.name: v.number for v in enum.value})
    return out


def method(name: str) -> str:
    """The gRPC path of an AsyncInference method.

    >>> method("GetActions")
    '/transport.AsyncInference/GetActions'
    """
    return f"/{SERVICE}/{name}"


def chunks(data: bytes) -> Iterator[Any]:
    """``data`` as Observation messages of at most CHUNK_BYTES, transfer states as LeRobot sends them."""
    m = messages()
    sent = 0
    while True:
        piece = data[sent:sent + CHUNK_BYTES]
        last = sent + CHUNK_BYTES >= len(data)
        state = m["TRANSFER_END"] if last else m["TRANSFER_BEGIN"] if sent == 0 else m["TRANSFER_MIDDLE"]
        yield m["Observation"](transfer_state=state, data=piece)
        sent += len(piece)
        if last:
            return


# -- our payload encoding: msgpack, numeric arrays only ----------------------------------------------------------


def _pack(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in "biuf":
            raise TypeError(f"only numeric arrays travel to a policy server, not dtype {value.dtype}")
        return {"__nd__": True, "dtype": value.dtype.str, "shape": list(value.shape),
                "data": np.ascontiguousarray(value).tobytes()}
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot send a {type(value).__name__} to a policy server")


def _unpack(obj: dict[str, Any]) -> Any:
    if obj.get("__nd__") is True:
        dtype = np.dtype(obj["dtype"])
        if dtype.kind not in "biuf":
            raise ValueError(f"refusing an array of dtype {dtype} (numeric arrays only)")
        return np.frombuffer(obj["data"], dtype).reshape(obj["shape"])
    return obj


def encode_payload(value: Mapping[str, Any]) -> bytes:
    """One payload (setup, observation or actions) as msgpack, marked with our format.

    >>> decode_payload(encode_payload({"actions": np.ones((2, 3), np.float32)}))["actions"].shape
    (2, 3)
    """
    return msgpack.packb({"format": FORMAT, **value}, default=_pack, use_bin_type=True)


def decode_payload(data: bytes) -> dict[str, Any]:
    """A payload :func:`encode_payload` wrote; ``ValueError`` for anything else (a pickle is never loaded).

    >>> decode_payload(b"\\x80\\x04K\\x01.")
    Traceback (most recent call last):
    ...
    ValueError: not an embagents-msgpack-1 payload (a pickle: LeRobot's own encoding, which this side never loads)
    """
    if data[:1] == b"\x80":  # pickle protocol 2+
        raise ValueError(f"not an {FORMAT} payload (a pickle: LeRobot's own encoding, which this side never loads)")
    try:
        value = msgpack.unpackb(data, object_hook=_unpack, raw=False)
    except Exception as exc:
        raise ValueError(f"not an {FORMAT} payload ({type(exc).__name__}: {exc})") from None
    if not isinstance(value, dict) or value.get("format") != FORMAT:
        raise ValueError(f"not an {FORMAT} payload")
    return value


# -- the client --------------------------------------------------------------------------------------------------


def check_chunk(actions: Any, observation: Mapping[str, np.ndarray], length: int | None, source: str) -> np.ndarray:
    """``actions`` as a float32 ``(length, n_joints)`` chunk (n_joints: the state's size); a
    :class:`PolicyError` naming both shapes otherwise. ``length`` None: any length.

    >>> check_chunk(np.zeros((8, 7)), {STATE_KEY: np.zeros(7)}, 10, "policy server gpu:8080")
    Traceback (most recent call last):
    ...
    embagents.models.lerobot.PolicyError: policy server gpu:8080 sent a chunk of shape (8, 7); expected (10, 7) (actions_per_chunk, n_joints)
    """
    actions = np.asarray(actions)
    state = observation.get(STATE_KEY)
    joints = int(np.size(state)) if state is not None else None
    numbers = actions.dtype.kind in "iuf"
    if actions.ndim != 2 or actions.shape[0] < 1 or not numbers or (length is not None and actions.shape[0] != length) \
            or (joints is not None and actions.shape[1] != joints):
        want = f"({length if length is not None else 'T'}, {joints if joints is not None else 'n_joints'})"
        raise PolicyError(f"{source} sent a chunk of shape {tuple(actions.shape)}"
                          f"{'' if numbers else f' dtype {actions.dtype}'}; expected {want} (actions_per_chunk, n_joints)"
                          f"{'' if numbers else ' of numbers'}")
    return np.ascontiguousarray(actions, np.float32)


def is_loopback(address: str) -> bool:
    """Whether ``host:port`` (or ``unix:PATH``) stays on this machine.

    >>> is_loopback("127.0.0.1:8080"), is_loopback("[::1]:8080"), is_loopback("localhost:1"), is_loopback("gpu:8080")
    (True, True, True, False)
    """
    if address.startswith(("unix:", "unix-abstract:")):
        return True
    host = address.rpartition(":")[0].strip("[]") or address
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a host name: assume it is another machine


class LeRobotPolicyClient:
    """A :class:`~embagents.models.policy.PolicyClient` for a LeRobot async-inference policy server.

    - ``address``: ``host:port`` of the server;
    - ``actions_per_chunk``: the chunk length asked for (and checked);
    - ``policy_type``, ``pretrained_name_or_path``, ``device``, ``lerobot_features``,
      ``rename_map``: the policy setup sent once per connection (LeRobot's ``RemotePolicyConfig``);
    - payloads are msgpack (never pickle): the server is :mod:`embagents.models.lerobot_server`
      or another that speaks it;
    - ``tls_ca``: a PEM file of the server's certificate (or its CA): the channel is TLS and the
      server must prove it holds that certificate's key; ``token``: a shared secret sent with every
      call (``authorization: Bearer``; TLS only: gRPC sends it over nothing else), which our server
      takes with ``--tls-cert``, ``--tls-key`` and ``--token-file``. Without them the channel is
      plaintext and unauthenticated, as LeRobot's own: a warning says so when it leaves the machine.
    """

    def __init__(self, address: str, *, actions_per_chunk: int, policy_type: str = "act",
                 pretrained_name_or_path: str = "", device: str = "cpu",
                 lerobot_features: Mapping[str, Any] | None = None, rename_map: Mapping[str, str] | None = None,
                 name: str = "lerobot", tls_ca: str | None = None, token: str | None = None) -> None:
        if int(actions_per_chunk) < 1:
            raise ValueError(f"actions_per_chunk must be >= 1, got {actions_per_chunk!r}")
        if token and not tls_ca:
            raise ValueError("a token needs TLS: pass tls_ca= (the server's certificate, PEM) as well; "
                             "over plaintext anyone on the way could read it")
        self._root_certificates: bytes | None = None
        if tls_ca:
            try:
                with open(os.path.expanduser(tls_ca), "rb") as f:
                    self._root_certificates = f.read()
            except OSError as exc:
                raise ValueError(f"cannot read tls_ca {tls_ca!r} ({exc.strerror}); pass the PEM certificate "
                                 "the policy server was started with (--tls-cert)") from None
        self._token = token
        self.address, self.name = address, name
        self.actions_per_chunk = int(actions_per_chunk)
        self.setup = {"policy_type": policy_type, "pretrained_name_or_path": pretrained_name_or_path,
                      "device": device, "actions_per_chunk": self.actions_per_chunk,
                      "lerobot_features": dict(lerobot_features or {}), "rename_map": dict(rename_map or {})}
        self._channel: Any = None
        self._ready = False
        self._timestep = 0
        if not is_loopback(address) and not tls_ca:
            log.warning("%s: the LeRobot gRPC channel to %s is plaintext and unauthenticated (LeRobot's protocol has "
                        "no keys): anyone on that network can read the observations and send the robot actions; "
                        "keep the policy server on this machine, reach it through a tunnel you trust (ssh -L, "
                        "WireGuard), or serve it with TLS and a token (tls_ca=, token=)", name, address)

    def __repr__(self) -> str:
        return f"LeRobotPolicyClient({self.address!r})"

    # -- connection ---------------------------------------------------------------------------------------------
    def _rpc(self, kind: str, name: str, response: str) -> Any:
        try:
            import grpc
        except ImportError as exc:
            raise ModuleNotFoundError(f"the LeRobot client needs grpcio: {_INSTALL_HINT}") from exc
        if self._channel is None:
            options = [("grpc.max_receive_message_length", 4 * CHUNK_BYTES), ("grpc.max_send_message_length", 4 * CHUNK_BYTES)]
            if self._root_certificates is None:
                self._channel = grpc.insecure_channel(self.address, options=options)
            else:
                creds = grpc.ssl_channel_credentials(root_certificates=self._root_certificates)
                if self._token:
                    creds = grpc.composite_channel_credentials(creds, grpc.access_token_call_credentials(self._token))
                self._channel = grpc.secure_channel(self.address, creds, options=options)
        m = messages()
        return getattr(self._channel, kind)(method(name), request_serializer=lambda msg: msg.SerializeToString(),
                                            response_deserializer=m[response].FromString)

    def _drop_channel(self) -> None:
        # A fresh channel after a failure: gRPC's own reconnect backoff would keep a restarted server away for seconds.
        channel, self._channel, self._ready = self._channel, None, False
        if channel is not None:
            channel.close()

    def _hello(self, deadline: float) -> None:
        m = messages()
        self._rpc("unary_unary", "Ready", "Empty")(m["Empty"](), timeout=_left(deadline))
        self._rpc("unary_unary", "SendPolicyInstructions", "Empty")(
            m["PolicySetup"](data=self._encode_setup()), timeout=_left(deadline))
        self._ready = True

    # -- the policy ---------------------------------------------------------------------------------------------
    def infer(self, observation: Mapping[str, np.ndarray], task: str, timeout_s: float) -> np.ndarray:
        """The chunk of actions for ``observation`` (float32, (actions_per_chunk, n_joints)).

        Raises :class:`PolicyUnavailable` (server down: the next call reconnects),
        :class:`PolicyLate` (no chunk within ``timeout_s``), :class:`PolicyError`
        (the server failed, or sent a chunk of the wrong shape), :class:`BadRequest`
        (the server refused the observation, saying why).
        """
        import grpc

        deadline = time.monotonic() + float(timeout_s)
        try:
            try:
                data = self._exchange(observation, task, deadline)
            except grpc.RpcError as exc:
                if exc.code() != grpc.StatusCode.FAILED_PRECONDITION:
                    raise
                # The server forgot our setup (it restarted, or another client said Ready): hello again, once.
                self._ready = False
                data = self._exchange(observation, task, deadline)
        except grpc.RpcError as exc:
            raise self._error(exc, float(timeout_s)) from None  # _ready is still False if the setup failed
        except _Late:
            self._ready = False
            raise PolicyLate(f"policy server {self.address} gave no actions within {timeout_s:.3f} s; "
                             "motion should stop until the next chunk") from None
        return self._check_chunk(self._decode_actions(data), observation)

    def _exchange(self, observation: Mapping[str, np.ndarray], task: str, deadline: float) -> bytes:
        """Hello (when needed), the observation out, its chunk's bytes back."""
        m = messages()
        if not self._ready:
            self._hello(deadline)
        self._timestep += 1
        payload = self._encode_observation(observation, task, self._timestep)
        self._rpc("stream_unary", "SendObservations", "Empty")(chunks(payload), timeout=_left(deadline))
        get = self._rpc("unary_unary", "GetActions", "Actions")
        while not (data := get(m["Empty"](), timeout=_left(deadline)).data):
            pass  # the server had no observation in time (LeRobot answers Empty): ask until the deadline
        return bytes(data)

    def _error(self, exc: Any, timeout_s: float) -> Exception:
        import grpc

        code, details = exc.code(), exc.details() or ""
        if code == grpc.StatusCode.DEADLINE_EXCEEDED:
            self._ready = False  # the server may have restarted meanwhile: say hello again
            return PolicyLate(f"policy server {self.address} gave no actions within {timeout_s:.3f} s; "
                              "motion should stop until the next chunk")
        if code == grpc.StatusCode.UNAVAILABLE:
            self._drop_channel()
            return PolicyUnavailable(
                f"policy server {self.address} is not reachable ({details.splitlines()[0] if details else code.name}); "
                "is it running? (LeRobot: python -m lerobot.async_inference.policy_server --host=HOST --port=PORT; "
                "embagents: python -m embagents.models.lerobot_server --onnx POLICY.onnx --port PORT). "
                "The next call reconnects")
        in_setup, self._ready = not self._ready, False
        if code == grpc.StatusCode.INVALID_ARGUMENT:
            return BadRequest(f"policy server {self.address} refused the request: {details}")
        if code == grpc.StatusCode.UNAUTHENTICATED:
            return PolicyError(f"policy server {self.address} refused this client: {details}; pass the token its "
                               "--token-file holds (token=)")
        hint = ""
        if code == grpc.StatusCode.UNKNOWN and in_setup:
            hint = (" (LeRobot's own policy_server reads pickles only, and embagents never sends or loads one: "
                    "serve the policy with python -m embagents.models.lerobot_server)")
        return PolicyError(f"policy server {self.address} failed: {code.name}: {details}{hint}")

    def _check_chunk(self, actions: np.ndarray, observation: Mapping[str, np.ndarray]) -> np.ndarray:
        return check_chunk(actions, observation, self.actions_per_chunk, f"policy server {self.address}")

    # -- payloads -----------------------------------------------------------------------------------------------
    def _encode_setup(self) -> bytes:
        return encode_payload(self.setup)

    def _encode_observation(self, observation: Mapping[str, np.ndarray], task: str, timestep: int) -> bytes:
        return encode_payload({"timestep": timestep, "timestamp": time.time(), "task": task, "must_go": True,
                               "observation": {k: np.asarray(v) for k, v in observation.items()}})

    def _decode_actions(self, data: bytes) -> np.ndarray:
        try:
            answer = decode_payload(data)
        except ValueError as exc:
            raise PolicyError(f"policy server {self.address} sent an unreadable chunk: {exc}") from None
        return np.asarray(answer.get("actions"), np.float32)

    def close(self) -> None:
        """Close the channel (a later call opens a new one)."""
        self._drop_channel()


class _Late(Exception):
    pass


def _left(deadline: float) -> float:
    left = deadline - time.monotonic()
    if left <= 0:
        raise _Late()
    return left
