"""A policy served over openpi's WebSocket protocol (:mod:`embagents.models.openpi`), so openpi's clients drive it.

:class:`OpenPIServer` serves any ``policy(observation, task) -> (T, N)``
function: one thread per connection, the metadata first, then one action
map per observation map, ``server_timing`` in each; a failure is answered
as openpi does (the traceback as a text frame, then close code 1011) and
logged; ``GET /healthz`` answers 200. Observation keys are taken in either
naming: nested maps are flattened and ``/`` read as ``.``
(``observation/state`` and ``{"observation": {"state": ...}}`` both reach
the policy as ``observation.state``); ``prompt`` is the task.

Who may connect: a handshake with an ``Origin`` header (a browser page) is
refused; with ``api_key`` set, ``Authorization: Api-Key KEY`` must match it
(compared in constant time; openpi's own server takes any key). Beyond
loopback :func:`check_bind` wants ``wss://`` (a certificate) or a key.

:func:`start_openpi` serves a loaded ONNX policy (a
:class:`~embagents.models.policy.PolicyServing`) this way: its model actor
does so when its options hold ``{"openpi": {"bind": ...}}``, as under
``embagents serve-policy`` or for a ``PolicyModel(openpi_bind=...)`` of a run.

Example::

    >>> server = OpenPIServer(lambda obs, task: np.zeros((4, 2), np.float32), {"policy": "zeros"})
    >>> port = server.start("127.0.0.1", 0)         # doctest: +SKIP
    >>> server.stop()                               # doctest: +SKIP
"""

from __future__ import annotations

import hmac
import http
import logging
import os
import threading
import time
import traceback
from collections.abc import Callable, Mapping
from typing import Any
from urllib.parse import urlsplit

import numpy as np

from embagents.models.lerobot import is_loopback
from embagents.models.openpi import MAX_MESSAGE_BYTES, normalize_key, packb, unpackb
from embagents.models.policy import PolicyServing

__all__ = ["OpenPIPolicyServing", "OpenPIServer", "check_bind", "flatten", "read_api_key", "serving_policy", "start_openpi"]

log = logging.getLogger("embagents.openpi_server")

Policy = Callable[[Mapping[str, np.ndarray], str], np.ndarray]


def check_bind(bind: str, *, api_key: bool, tls: bool) -> tuple[str, str, int]:
    """``(scheme, host, port)`` of ``ws://HOST:PORT`` / ``wss://HOST:PORT``; ``ValueError`` naming the fix.

    >>> check_bind("ws://127.0.0.1:8000", api_key=False, tls=False)
    ('ws', '127.0.0.1', 8000)
    >>> check_bind("ws://0.0.0.0:8000", api_key=False, tls=False)
    Traceback (most recent call last):
    ...
    ValueError: ws://0.0.0.0:8000 reaches beyond this machine with neither TLS nor a key: anyone on the network could drive the policy; pass --api-key-file FILE (clients send Authorization: Api-Key ...) and/or bind wss:// with --tls-cert CERT.pem --tls-key KEY.pem, or bind ws://127.0.0.1:PORT
    """

    parts = urlsplit(bind)
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme not in ("ws", "wss") or parts.hostname is None or port is None:
        raise ValueError(f"--bind {bind!r}: expected ws://HOST:PORT or wss://HOST:PORT (e.g. ws://127.0.0.1:8000)")
    if parts.scheme == "wss" and not tls:
        raise ValueError(f"{bind} is wss:// (TLS): pass --tls-cert CERT.pem and --tls-key KEY.pem")
    if parts.scheme == "ws" and tls:
        raise ValueError(f"{bind}: --tls-cert/--tls-key are given but the bind is ws://; bind wss://{parts.netloc}")
    if not is_loopback(parts.netloc) and parts.scheme == "ws" and not api_key:
        raise ValueError(f"{bind} reaches beyond this machine with neither TLS nor a key: anyone on the network could "
                         "drive the policy; pass --api-key-file FILE (clients send Authorization: Api-Key ...) and/or "
                         "bind wss:// with --tls-cert CERT.pem --tls-key KEY.pem, or bind ws://127.0.0.1:PORT")
    return parts.scheme, parts.hostname, port


def read_api_key(path: str) -> str:
    """The key in ``path`` (its first line), refused when others may read the file."""
    try:
        st = os.stat(path)
        with open(path, encoding="utf-8") as f:
            key = f.readline().strip()
    except OSError as exc:
        raise ValueError(f"cannot read --api-key-file {path!r} ({exc.strerror})") from None
    if st.st_mode & 0o077:
        raise ValueError(f"--api-key-file {path!r} is readable by others (mode {st.st_mode & 0o777:o}); "
                         f"chmod 600 {path}")
    if len(key) < 16:
        raise ValueError(f"--api-key-file {path!r} holds a key of {len(key)} characters; use at least 16 "
                         "(python -c 'import secrets; print(secrets.token_urlsafe(32))')")
    return key


def flatten(observation: Mapping[Any, Any], prefix: str = "") -> dict[str, Any]:
    """Nested maps as one level of ``.``-joined keys, ``/`` read as ``.``.

    >>> sorted(flatten({"observation/state": 1, "images": {"front": 2}}))
    ['images.front', 'observation.state']
    """
    out: dict[str, Any] = {}
    for key, value in observation.items():
        name = prefix + normalize_key(key.decode() if isinstance(key, bytes) else str(key))
        if isinstance(value, Mapping):
            out.update(flatten(value, name + "."))
        else:
            out[name] = value
    return out


class OpenPIServer:
    """openpi's protocol for one ``policy`` (see the module docstring); ``delay_s`` is added to each inference."""

    def __init__(self, policy: Policy, metadata: Mapping[str, Any], *, api_key: str | None = None,
                 delay_s: float = 0.0, name: str = "policy") -> None:
        self.policy, self.metadata, self.api_key = policy, dict(metadata), api_key
        self.delay_s, self.name = float(delay_s), name
        self.served = self.failed = self.refused = 0
        self._server: Any = None
        self._thread: threading.Thread | None = None

    # -- the handshake ------------------------------------------------------------------------------------------
    def _process_request(self, connection: Any, request: Any) -> Any:
        if urlsplit(request.path).path == "/healthz":
            return connection.respond(http.HTTPStatus.OK, "OK\n")
        if request.headers.get("Origin") is not None:
            self.refused += 1
            log.warning("refused a handshake from a browser page (Origin %s)", request.headers.get("Origin"))
            return connection.respond(http.HTTPStatus.FORBIDDEN, "browser pages may not drive a policy\n")
        if self.api_key is not None:
            scheme, _, given = (request.headers.get("Authorization") or "").partition(" ")
            # constant time: a wrong guess says nothing about the right key
            if scheme.lower() != "api-key" or not hmac.compare_digest(given.strip().encode(), self.api_key.encode()):
                self.refused += 1
                log.warning("refused a client without the right API key (%s)", connection.remote_address)
                return connection.respond(http.HTTPStatus.UNAUTHORIZED, "send Authorization: Api-Key <key>\n")
        return None

    # -- a connection -------------------------------------------------------------------------------------------
    def _handle(self, ws: Any) -> None:
        from websockets.exceptions import ConnectionClosed
        from websockets.frames import CloseCode

        peer = ws.remote_address  # read now: a closed socket no longer knows it
        log.info("client %s connected", peer)
        prev_total: float | None = None
        try:
            ws.send(packb(self.metadata))
            while True:
                message = ws.recv()
                start = time.monotonic()
                try:
                    if isinstance(message, str):
                        raise ValueError("expected a binary msgpack observation, got a text frame")
                    actions = self._infer(message)
                    infer_ms = (time.monotonic() - start) * 1000.0
                    timing = {"infer_ms": infer_ms, **({"prev_total_ms": prev_total} if prev_total is not None else {})}
                    answer = packb({"actions": actions, "server_timing": timing})
                except Exception:
                    self.failed += 1
                    text = traceback.format_exc()
                    log.warning("inference failed; the client gets the traceback and close 1011:\n%s", text)
                    ws.send(text)
                    ws.close(CloseCode.INTERNAL_ERROR, "Internal server error. Traceback included in previous frame.")
                    return
                ws.send(answer)
                self.served += 1
                prev_total = (time.monotonic() - start) * 1000.0
        except ConnectionClosed:
            log.info("client %s disconnected", peer)

    def _infer(self, message: bytes) -> np.ndarray:
        raw = unpackb(message)
        if not isinstance(raw, dict):
            raise ValueError(f"expected an observation map, got a {type(raw).__name__}")
        observation = flatten(raw)
        task = observation.pop("prompt", "")
        if not isinstance(task, str):
            raise ValueError(f"'prompt' must be text, got {type(task).__name__}")
        observation = {k: v for k, v in observation.items() if isinstance(v, np.ndarray)}
        actions = np.asarray(self.policy(observation, task), np.float32)
        if self.delay_s:
            time.sleep(self.delay_s)
        return actions

    # -- lifecycle ----------------------------------------------------------------------------------------------
    def start(self, host: str, port: int, ssl_context: Any = None) -> int:
        """Listen on ``host:port`` (0: any free port) in a thread; returns the port."""
        from websockets.sync.server import serve

        logging.getLogger("websockets.server").setLevel(logging.WARNING)  # a line per connection is ours to log
        try:
            self._server = serve(self._handle, host, port, ssl=ssl_context, compression=None,
                                 max_size=MAX_MESSAGE_BYTES, process_request=self._process_request,
                                 ping_interval=None, server_header=None)
        except OSError as exc:
            raise ValueError(f"cannot listen on {host}:{port} ({exc.strerror or exc}); is something else serving "
                             "there? pick another --bind port") from None
        bound = int(self._server.socket.getsockname()[1])
        self._thread = threading.Thread(target=self._server.serve_forever, name="openpi-server", daemon=True)
        self._thread.start()
        return bound

    def stop(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.shutdown()
        if self._thread is not None:
            self._thread.join(timeout=5)


def serving_policy(serving: Any) -> tuple[Policy, dict[str, Any]]:
    """A policy serving (:class:`~embagents.models.policy.PolicyServing`) as a function, and the metadata it offers.

    The metadata names the observation keys it needs with their shapes, and the chunk's shape
    (from one run on zeros): what a client checks its key mapping against.
    """
    def policy(observation: Mapping[str, np.ndarray], task: str) -> np.ndarray:
        inputs = {"observation": dict(observation)}
        serving.check("act", inputs, {})  # BadRequest names a missing key or a wrong shape
        return np.asarray(next(iter(serving.run("act", inputs, {})))["actions"], np.float32)

    expected = getattr(serving, "expected", {})
    zeros = {k: np.zeros([d if isinstance(d, int) else 1 for d in shape[1:]], dtype)
             for k, (shape, dtype) in expected.items()}
    chunk = policy(zeros, "")
    metadata = {
        "server": "embagents serve-policy",
        "observation_keys": list(expected),
        "observation_shapes": {k: [d if isinstance(d, int) else None for d in shape[1:]]
                               for k, (shape, _) in expected.items()},
        "action_key": "actions",
        "actions_per_chunk": int(chunk.shape[0]),
        "action_dim": int(chunk.shape[1]) if chunk.ndim == 2 else None,
    }
    return policy, metadata


def start_openpi(serving: Any, name: str, bind: str, api_key_file: str | None = None, tls_cert: str | None = None,
                 tls_key: str | None = None, delay_ms: float = 0.0) -> OpenPIServer:
    """Serve a loaded policy ``serving`` over openpi's protocol on ``bind`` (what a policy model actor does when its
    options hold ``{"openpi": {...}}``: ``embagents serve-policy``, or a ``PolicyModel(openpi_bind=...)`` of a run).

    The API key is read from ``api_key_file`` and TLS from its files here, in the serving
    process: no secret crosses a socket.
    """
    scheme, host, port = check_bind(bind, api_key=bool(api_key_file), tls=bool(tls_cert))
    ssl_context = None
    if scheme == "wss":
        import ssl

        ssl_context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        ssl_context.load_cert_chain(tls_cert, tls_key)  # type: ignore[arg-type]
    api_key = read_api_key(api_key_file) if api_key_file else None
    policy, metadata = serving_policy(serving)
    server = OpenPIServer(policy, metadata, api_key=api_key, delay_s=float(delay_ms) / 1000.0, name=name)
    bound = server.start(host, port, ssl_context)
    log.info("serving policy %s over openpi's protocol on %s://%s:%d%s", name, scheme, host, bound,
             " (API key required)" if api_key else "")
    return server


class OpenPIPolicyServing(PolicyServing):
    """An ONNX policy's serving that also serves it over openpi's protocol (options ``{"openpi": {"bind", ...}}``).

    A model actor of kind ``policy`` gets it for such options: ``embagents serve-policy``, or a
    ``PolicyModel(openpi_bind=...)`` in a system. The server starts once the policy is loaded
    (after the process's priority is raised: its threads inherit it) and stops with it.
    """

    def __init__(self, path: str, options: dict[str, Any]) -> None:
        super().__init__(path, options)
        self.openpi_options = dict(options["openpi"])
        self.openpi_name = str(self.openpi_options.pop("name", "") or os.path.splitext(os.path.basename(path))[0])
        self.openpi: OpenPIServer | None = None

    def load(self) -> None:
        super().load()
        self.openpi = start_openpi(self, self.openpi_name, **self.openpi_options)

    def close(self) -> None:
        server, self.openpi = self.openpi, None
        if server is not None:
            server.stop()
        super().close()
