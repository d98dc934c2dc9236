"""Model actors on another machine: the inference protocol over TCP with ZeroMQ CURVE.

A :class:`RemoteModelActor` is a model actor whose inference ROUTER is bound
on ``<run>/<name>.inf`` (for the host's own components) and on TCP endpoints
as a CURVE server: only clients whose public key is on its allow list get a
connection (:class:`actors.curve.CurveAllowList` logs each refused key and
address). ``embagents serve-model`` runs one under the supervisor.

A :class:`RemoteModelClient` reaches it with the client API of
:class:`~embagents.models.LocalModelClient` (``stream``, ``infer``, ``chat``,
``detect``) and the same protocol. Its frames are encoded by a codec with no
shared memory (arrays are copied into the frame: a segment on the robot means
nothing on the GPU box), and the server decodes what comes over TCP with no
shared memory either (a remote peer cannot make it map one of its host's
segments). The client pins the server's public key; a refused handshake fails
the waiting request at once with :class:`RemoteRefused`, naming the likely cause.

Example::

    >>> client = RemoteModelClient("tcp://gpu-box:5555", server_key="x" * 40, key=secret_file)  # doctest: +SKIP
    >>> client.chat([{"role": "user", "content": "hi"}])["content"]                          # doctest: +SKIP
"""

from __future__ import annotations

import logging
import os
import re
from typing import Any

import zmq

from actors import check_folder
from actors.codec import MAX_FRAME_BYTES, Codec
from actors.curve import (
    CurveAllowList,
    curve_client,
    curve_server,
    load_public_key,
    load_secret_key,
    raise_fd_limit,
)
from actors.runtime import current
from embagents.models.actor import ModelActor
from embagents.models.client import LocalModelClient, _Conn
from embagents.models.protocol import ModelUnavailable

__all__ = ["RemoteModelActor", "RemoteModelClient", "RemoteRefused", "check_binds", "default_secret_key", "keys_dir"]

log = logging.getLogger("embagents.model")

#: Without shared memory: arrays travel inside the frame, and handles are refused on decode.
_COPY_CODEC = Codec()
#: A silent peer (a host that vanished without closing its TCP connection) counts as gone after this.
HEARTBEAT_IVL_MS, HEARTBEAT_TIMEOUT_MS = 2000, 6000
#: Failed handshakes in a row (libzmq retries every ~0.1-0.2 s) that mean the server's key is not the pinned one.
_HANDSHAKE_TRIES = 3


class RemoteRefused(ModelUnavailable):
    """The CURVE handshake with a remote model actor failed: a key is not the one the other end expects."""


def keys_dir() -> str:
    """``$XDG_CONFIG_HOME/embagents/keys`` (default ``~/.config``): this user's, mode 0700, checked."""
    config = os.environ.get("XDG_CONFIG_HOME") or os.path.join(os.path.expanduser("~"), ".config")
    parent = os.path.join(config, "embagents")
    os.makedirs(parent, exist_ok=True)
    return check_folder(os.path.join(parent, "keys"))


def default_secret_key() -> str:
    """The secret key file ``embagents keys`` writes when no folder is named."""
    return os.path.join(keys_dir(), "embagents.key_secret")


def check_binds(binds: list[str], secret_key: str | None, allowed: list[str]) -> None:
    """Refuse TCP without CURVE: every ``tcp://`` bind needs a secret key file and allowed client keys.

    >>> check_binds(["tcp://0.0.0.0:5555"], None, [])
    Traceback (most recent call last):
    ...
    ValueError: tcp://0.0.0.0:5555: unauthenticated TCP is not offered; make keys with `embagents keys` and pass --key SECRETFILE and --allow CLIENT_PUBKEY (one per client)
    """
    for b in binds:
        if not re.fullmatch(r"tcp://[^/]+:\d+", b):
            raise ValueError(f"{b!r} is not a TCP endpoint; bind tcp://HOST:PORT (e.g. tcp://0.0.0.0:5555)")
        if not secret_key or not allowed:
            raise ValueError(f"{b}: unauthenticated TCP is not offered; make keys with `embagents keys` and pass "
                             "--key SECRETFILE and --allow CLIENT_PUBKEY (one per client)")


class RemoteModelActor(ModelActor):
    """A :class:`ModelActor` also bound on ``binds`` (tcp://) as a CURVE server for ``allowed`` keys.

    Args are plain data: the secret key is read from ``secret_key`` (a file only
    its owner can read) at every start, so it never crosses a socket.
    """

    def __init__(self, kind: str, path: str, options: dict[str, Any] | None = None, warmup: bool = True,
                 batch: dict[str, Any] | None = None, binds: list[str] | None = None, secret_key: str = "",
                 allowed: list[str] | None = None) -> None:
        super().__init__(kind, path, options, warmup, batch)
        self.binds, self.secret_key, self.allowed = list(binds or []), secret_key, list(allowed or [])
        check_binds(self.binds, secret_key, self.allowed)

    def on_start(self) -> None:
        super().on_start()  # loads the model, binds the ipc endpoint (no CURVE: it is this host's)
        _, secret = load_secret_key(self.secret_key)
        self.auth = CurveAllowList(current().ctx, [load_public_key(k) for k in self.allowed], watch=self.sock)
        curve_server(self.sock, secret)  # and a 5 s handshake limit: silent peers do not keep their fds
        fds = raise_fd_limit()  # connections that never finish a handshake must not run us out of fds
        self.sock.maxmsgsize = MAX_FRAME_BYTES  # an allowed peer still cannot make us buffer more
        for b in self.binds:
            try:
                self.sock.bind(b)
            except zmq.ZMQError as exc:
                self.auth.close()
                raise ValueError(f"cannot bind {b}: {exc}; is something else listening there, or is the address "
                                 "not one of this host's? pick another --bind") from None
        log.info("serving %s on %s for %d allowed key(s) (up to %d open files)", self.name, ", ".join(self.binds),
                 len(self.allowed), fds)

    def _decode(self, frame: zmq.Frame, mapped: list[list[Any]]) -> Any:
        try:
            frame.get("User-Id")  # set by the allow list: the peer came over CURVE
        except zmq.ZMQError:
            return super()._decode(frame, mapped)
        return _COPY_CODEC.decode(frame.bytes)

    def on_receive(self, message: Any) -> Any:
        if message == "stats":
            return {**super().on_receive(message), "refused_keys": self.auth.refused}
        return super().on_receive(message)

    def on_stop(self) -> None:
        super().on_stop()
        auth = getattr(self, "auth", None)  # None: the start failed before the allow list ran
        if auth is not None:
            auth.close()


class RemoteModelClient(LocalModelClient):
    """Reaches the model actor served at ``endpoint`` (``embagents serve-model``) over CURVE.

    ``server_key``: the server's public key (or its ``.key`` file), pinned;
    ``key``: this client's secret key file (default: the one ``embagents
    keys`` wrote); ``name``: shown in errors (default: the endpoint).
    """

    #: Not a model actor of this run: ``embagents supervise`` starts nothing for it.
    in_run = False

    def __init__(self, endpoint: str, *, server_key: str, key: str | None = None, timeout: float = 120.0,
                 name: str | None = None) -> None:
        if not re.fullmatch(r"tcp://[^/]+:\d+", endpoint):
            raise ValueError(f"{endpoint!r} is not a TCP endpoint; pass tcp://HOST:PORT of `embagents serve-model`")
        super().__init__("remote", timeout=timeout)
        self.name = name or endpoint
        self.endpoint = endpoint
        self.server_key = load_public_key(server_key)
        self.key_file = key or default_secret_key()
        self.public, self._secret = load_secret_key(self.key_file)

    def __repr__(self) -> str:
        return f"RemoteModelClient({self.endpoint!r})"

    def _connect(self, rt: Any) -> _Conn:
        return _CurveConn(rt, self.endpoint, self._secure)

    def _secure(self, sock: zmq.Socket) -> None:
        curve_client(sock, self.server_key, self.public, self._secret)
        sock.heartbeat_ivl, sock.heartbeat_timeout = HEARTBEAT_IVL_MS, HEARTBEAT_TIMEOUT_MS

    def _codec(self, rt: Any) -> Any:
        return _COPY_CODEC

    def _on_event(self, conn: _Conn, event: int, before: bool = False) -> bool:
        assert isinstance(conn, _CurveConn)
        if event == zmq.EVENT_HANDSHAKE_SUCCEEDED:
            conn.up, conn.failures = True, 0
        elif event == zmq.EVENT_HANDSHAKE_FAILED_AUTH:
            self._drop_conn()  # libzmq does not retry a refused key: the next request tries anew
            raise RemoteRefused(
                f"{self.endpoint} refused this client's key {self.public.decode()} (from {self.key_file}): it is "
                "not on the server's allow list; add it there (`embagents serve-model ... --allow "
                f"{self.public.decode()}`)"
            )
        elif event & (zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL | zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL):
            conn.up = False
            conn.failures += 1  # once may be a server dying mid-handshake; again and again is a wrong key
            if conn.failures >= _HANDSHAKE_TRIES:
                self._drop_conn()
                raise RemoteRefused(
                    f"the CURVE handshake with {self.endpoint} failed {conn.failures} times: its key is not "
                    f"server_key {self.server_key.decode()} (check the public key `embagents serve-model` printed) "
                    "or it does not speak CURVE"
                )
        elif event == zmq.EVENT_DISCONNECTED and not conn.up:
            return True  # a connection that never got through its handshake carried no request
        elif event == zmq.EVENT_DISCONNECTED:
            conn.up = False
            return before
        return True


class _CurveConn(_Conn):
    """A connection that knows whether its CURVE handshake went through."""

    up = False
    failures = 0
