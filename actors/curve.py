"""ZeroMQ CURVE for sockets that leave the machine: key files, pinned servers, an allow list.

CURVE (Curve25519 handshake, then every frame encrypted and authenticated)
protects both ends of a TCP connection: a client pins the server's public key
(a server without its secret key fails the handshake), and the server asks
:class:`CurveAllowList` (a ZAP handler, RFC 27) whether the client's public key
is one it was given; anything else is refused before a single frame of the
peer reaches the socket, and the refusal is logged with the key and address.

Key files use the ZeroMQ certificate format (``zmq.auth.load_certificate``
reads them): ``NAME.key`` holds the public key, ``NAME.key_secret`` both keys
and is created mode 0600 with ``O_EXCL``; a secret key file that group or
others can read is refused, as ssh refuses an open private key.

Example::

    >>> import tempfile
    >>> folder = tempfile.mkdtemp()
    >>> public, secret_file = write_keypair(folder, "robot")
    >>> load_public_key(public.decode()) == public == load_secret_key(secret_file)[0]
    True
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import re
import socket
import stat
import threading
import time
from collections.abc import Iterable, Mapping
from typing import Any

import zmq
import zmq.auth
from zmq.utils import z85
from zmq.utils.monitor import parse_monitor_message

from actors.errors import ActorError

__all__ = [
    "CurveAllowList",
    "KeyFileError",
    "curve_client",
    "curve_server",
    "is_public_key",
    "raise_fd_limit",
    "load_public_key",
    "load_secret_key",
    "write_keypair",
]

log = logging.getLogger("actors.curve")

#: The in-process endpoint libzmq asks for ZAP decisions (one handler per context).
ZAP_ENDPOINT = "inproc://zeromq.zap.01"
#: How long a TCP peer has to finish its handshake: connections that never do hold a file
#: descriptor each, and enough of them kept every allowed client out (libzmq's default is 30 s).
HANDSHAKE_IVL_MS = 5000
_FAILED = zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL | zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL


class KeyFileError(ActorError, ValueError):
    """A CURVE key or key file that cannot be used (the message names the fix)."""


def is_public_key(text: str) -> bool:
    """True for a Z85-encoded 32-byte key (40 characters).

    >>> is_public_key("x" * 40), is_public_key("short")
    (True, False)
    """
    if len(text) != 40:
        return False
    try:
        return len(z85.decode(text.encode())) == 32
    except (ValueError, KeyError, TypeError):
        return False


def write_keypair(folder: str, name: str) -> tuple[bytes, str]:
    """Make a key pair; write ``NAME.key`` (public) and ``NAME.key_secret`` (0600, new) in ``folder``.

    Returns the public key (Z85) and the secret file's path. An existing
    secret file is never overwritten.
    """
    if not re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.-]*", name):
        raise KeyFileError(f"key name {name!r} must be letters, digits, '_', '.', '-' (a file name, not a path)")
    public, secret = zmq.curve_keypair()
    stamp = time.strftime("%Y-%m-%d %H:%M:%S")
    body = f'\nmetadata\ncurve\n    public-key = "{public.decode()}"\n'
    secret_path = os.path.join(folder, f"{name}.key_secret")
    try:
        fd = os.open(secret_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        raise KeyFileError(f"{secret_path} exists; keys are never overwritten: pick another name "
                        f"or remove the old pair (`rm {secret_path} {secret_path[:-7]}`)") from None
    with os.fdopen(fd, "w") as f:
        f.write(f"#   ZeroMQ CURVE secret key, made {stamp}: never give this file away\n{body}"
                f'    secret-key = "{secret.decode()}"\n')
    public_path = os.path.join(folder, f"{name}.key")
    with open(public_path, "w") as f:
        f.write(f"#   ZeroMQ CURVE public key, made {stamp}: give it to the peers that must accept you\n{body}")
    return public, secret_path


def load_public_key(key_or_file: str) -> bytes:
    """A Z85 public key given as itself or as a key file (``NAME.key`` or ``NAME.key_secret``)."""
    if is_public_key(key_or_file):
        return key_or_file.encode()
    key_or_file = os.path.expanduser(key_or_file)
    if not os.path.isfile(key_or_file):
        raise KeyFileError(f"{key_or_file!r} is neither a public key (40 Z85 characters, as `embagents keys` "
                        "prints) nor a key file; pass one of these")
    public, _ = _load(key_or_file)
    return public


def load_secret_key(path: str) -> tuple[bytes, bytes]:
    """(public, secret) from a secret key file only this user can read (``~`` is expanded)."""
    path = os.path.expanduser(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise KeyFileError(f"no secret key file {path}: make one with `embagents keys`") from None
    if st.st_uid != os.getuid() or st.st_mode & 0o077:
        _refuse_public(path)  # a public key file (NAME.key) is readable by all, and is the likelier mistake
        raise KeyFileError(f"refusing the secret key file {path}: mode {oct(stat.S_IMODE(st.st_mode))[2:]}, owner uid "
                        f"{st.st_uid}; it must be yours and private. Fix: `chmod 600 {path}` (and make it yours)")
    public, secret = _load(path)
    if secret is None:
        _refuse_public(path)
        raise KeyFileError(f"{path} holds a public key only; pass the NAME.key_secret file `embagents keys` wrote")
    return public, secret


def _refuse_public(path: str) -> None:
    """Raise, naming the secret file to pass instead, if ``path`` holds a public key only."""
    try:
        secret = zmq.auth.load_certificate(path)[1]
    except (ValueError, OSError):
        return
    if secret is None:
        hint = f"pass {path}_secret" if os.path.isfile(f"{path}_secret") else "pass the NAME.key_secret file `embagents keys` wrote"
        raise KeyFileError(f"{path} is a public key (it holds no secret key): {hint}")


def _load(path: str) -> tuple[bytes, bytes | None]:
    try:
        public, secret = zmq.auth.load_certificate(path)
    except (ValueError, OSError) as exc:
        raise KeyFileError(f"{path} is not a ZeroMQ key file ({exc}); make keys with `embagents keys`") from None
    if public is None or not is_public_key(public.decode(errors="replace")):
        raise KeyFileError(f"{path} has no valid public-key line; make keys with `embagents keys`")
    return public, secret


def curve_server(sock: zmq.Socket, secret_key: bytes, domain: str = "embagents") -> None:
    """Make the binds ``sock`` makes from now on CURVE servers (earlier ipc binds stay as they are).

    Their peers get :data:`HANDSHAKE_IVL_MS` to finish the handshake.
    """
    sock.curve_server = True
    sock.curve_secretkey = secret_key
    sock.zap_domain = domain.encode()
    sock.handshake_ivl = HANDSHAKE_IVL_MS


def raise_fd_limit() -> int:
    """Raise this process's soft limit on open files to its hard limit (a server's TCP peers each
    hold one); returns the limit now in force."""
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft != hard:
        with contextlib.suppress(ValueError, OSError):
            resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
            soft = hard
    return soft


def curve_client(sock: zmq.Socket, server_key: bytes, public: bytes, secret: bytes) -> None:
    """Make the connects ``sock`` makes from now on CURVE clients of the server with ``server_key``."""
    sock.curve_serverkey = server_key
    sock.curve_publickey = public
    sock.curve_secretkey = secret


class CurveAllowList:
    """The ZAP handler of ``ctx``: CURVE clients whose public key is in ``allowed`` get in.

    It runs on its own thread (a handshake never waits for a busy actor loop),
    answers every other mechanism with a refusal, logs each refused key and
    address, and counts them in ``refused``. The user id of an accepted peer
    is its public key (``frame.get("User-Id")`` on what it sends).

    ``watch``: the CURVE server socket; libzmq refuses a peer that speaks
    another mechanism (NULL, PLAIN) or fails the handshake before it asks
    ZAP, so the socket's monitor events tell of those: each is logged with
    the peer's address and counted too.
    """

    def __init__(self, ctx: zmq.Context, allowed: Iterable[bytes], watch: zmq.Socket | None = None) -> None:
        self.allowed = frozenset(allowed)
        if not self.allowed:
            raise KeyFileError("no client key is allowed, so no client could connect: pass --allow PUBKEY (or a .key file)")
        self.refused = 0
        self._sock = ctx.socket(zmq.REP)
        self._sock.linger = 0
        self._sock.bind(ZAP_ENDPOINT)  # before any CURVE bind: without a handler libzmq lets every key in
        self._wake_rx = ctx.socket(zmq.PAIR)
        self._wake_rx.bind(f"inproc://curve-allow-stop-{id(self)}")
        self._wake_tx = ctx.socket(zmq.PAIR)
        self._wake_tx.connect(f"inproc://curve-allow-stop-{id(self)}")
        self._monitor: zmq.Socket | None = None
        if watch is not None:
            events = zmq.EVENT_ACCEPTED | zmq.EVENT_DISCONNECTED | _FAILED
            self._monitor = watch.get_monitor_socket(events, f"inproc://curve-allow-monitor-{id(self)}")
        self._peers: dict[int, str] = {}  # fd of an accepted TCP connection -> the peer's address
        self._failed: str | None = None  # why the handshake of the connection about to disconnect failed
        self._thread = threading.Thread(target=self._serve, name="curve-allow-list", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        poller = zmq.Poller()
        poller.register(self._sock, zmq.POLLIN)
        poller.register(self._wake_rx, zmq.POLLIN)
        if self._monitor is not None:
            poller.register(self._monitor, zmq.POLLIN)
        try:
            while True:
                ready = dict(poller.poll())
                if self._wake_rx in ready:
                    break
                if self._sock in ready:
                    self._sock.send_multipart(self.decide(self._sock.recv_multipart()))
                if self._monitor is not None and self._monitor in ready:
                    self._on_event(parse_monitor_message(self._monitor.recv_multipart()))
        except zmq.ContextTerminated:
            pass  # the process is ending without close(): nothing more to decide
        for s in (self._sock, self._wake_rx, self._monitor):
            if s is not None:
                s.close(0)

    def _on_event(self, event: Mapping[str, Any]) -> None:
        """Log a peer that failed the handshake before ZAP was asked, with its address."""
        kind, value = event["event"], event["value"]
        if kind == zmq.EVENT_ACCEPTED:  # value: the connection's fd, still open here (or reused: best effort)
            self._peers[value] = _peer_address(value)
        elif kind & _FAILED:
            # libzmq reports the failure, then at once the disconnect of its connection (by fd).
            self._failed = _failure_text(kind, value)
        elif kind == zmq.EVENT_DISCONNECTED:
            address = self._peers.pop(value, "an unknown address")
            if self._failed is not None:
                self.refused += 1
                log.warning("refused a client from %s: %s", address, self._failed)
            self._failed = None

    def decide(self, request: list[bytes]) -> list[bytes]:
        """The ZAP reply frames to one ZAP request's frames."""
        if len(request) < 6 or request[0] != b"1.0":
            log.warning("refused a connection: malformed ZAP request of %d frames", len(request))
            return [b"1.0", request[1] if len(request) > 1 else b"", b"400", b"malformed ZAP request", b"", b""]
        rid, address, mechanism, creds = request[1], request[3].decode(errors="replace"), request[5], request[6:]
        key = z85.encode(creds[0]) if mechanism == b"CURVE" and len(creds) == 1 and len(creds[0]) == 32 else None
        if key is not None and key in self.allowed:
            return [b"1.0", rid, b"200", b"OK", key, b""]
        self.refused += 1
        who = f"public key {key.decode()}" if key is not None else f"mechanism {mechanism.decode(errors='replace')}"
        log.warning("refused a client from %s: %s is not on the allow list (add it with --allow if it is yours)",
                    address, who)
        return [b"1.0", rid, b"400", b"key not allowed", b"", b""]

    def close(self) -> None:
        """Stop the handler thread (call before the watched socket and the context go)."""
        if self._thread.is_alive():
            self._wake_tx.send(b"")
            self._thread.join(5)
        self._wake_tx.close(0)


def _peer_address(fd: int) -> str:
    """``host:port`` of the TCP peer on ``fd`` (a duplicate is asked, so libzmq's own fd stays as it is)."""
    unknown = "an address not known (its connection closed before it could be looked up)"
    try:
        dup = os.dup(fd)
    except OSError:
        return unknown
    try:
        s = socket.socket(fileno=dup)
    except OSError:  # not a socket (any more): the fd was closed and reused
        os.close(dup)
        return unknown
    try:
        with s:
            peer = s.getpeername()
    except OSError:
        return unknown
    return f"{peer[0]}:{peer[1]}" if isinstance(peer, tuple) else str(peer)


def _failure_text(kind: int, value: int) -> str:
    """Why a peer's handshake failed, in words, from its monitor event."""
    if kind == zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL:
        if value == zmq.PROTOCOL_ERROR_ZMTP_MECHANISM_MISMATCH:
            return "it does not speak CURVE (a NULL or PLAIN client)"
        try:
            name = (zmq.Event(value).name or hex(value)).lower().replace("_", " ")
        except ValueError:
            name = f"protocol error {value:#x}"
        return f"its handshake failed ({name}): a wrong server key, or not a ZeroMQ client"
    if value == errno.EAGAIN:  # the handshake timer
        return f"it did not finish its handshake within {HANDSHAKE_IVL_MS / 1000:g} s"
    if value in (errno.EPIPE, errno.ECONNRESET):  # it gave up first, on our greeting
        return "it hung up during the handshake (a NULL or PLAIN client, or one pinning another server key)"
    return f"its handshake failed ({zmq.strerror(value) if value else 'no detail'})"
