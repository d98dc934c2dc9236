"""A policy server that speaks LeRobot's async-inference gRPC protocol, with msgpack payloads (never pickle).

It serves any ``policy(observation, task) -> (T, N) actions`` function; from
the command line, an ONNX policy on onnxruntime (each model input named by an
observation key such as ``observation.state``, a batch dimension of 1 added;
the first output is the chunk, ``(1, T, N)`` or ``(T, N)``)::

    python -m embagents.models.lerobot_server --onnx reach.onnx --host 127.0.0.1 --port 8080

Robots reach it with :class:`~embagents.models.lerobot.LeRobotPolicyClient`.
As LeRobot's server does, it keeps only the latest observation, answers
``GetActions`` with an empty chunk when none comes within
``obs_queue_timeout_s``, and can add a fixed ``latency_s`` (to test a late
answer). A payload that is not ours (a pickle from LeRobot's own client) is
refused with INVALID_ARGUMENT, never loaded.

Example::

    >>> server = PolicyServer(lambda obs, task: np.zeros((4, 2), np.float32))
    >>> port = server.start("127.0.0.1:0")          # doctest: +SKIP
    >>> server.stop()                               # doctest: +SKIP
"""

from __future__ import annotations

import argparse
import hmac
import io
import logging
import queue
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent import futures
from typing import Any

import numpy as np

from embagents.models.lerobot import SERVICE, decode_payload, encode_payload, messages
from embagents.models.policy import PolicyServing

__all__ = ["PolicyServer", "main", "onnx_policy"]

log = logging.getLogger("embagents.lerobot_server")

Policy = Callable[[Mapping[str, np.ndarray], str], np.ndarray]


def onnx_policy(path: str, threads: int | None = 1) -> Policy:
    """An ONNX file as a policy function: the model layer's ONNX policy serving (its checks name bad keys and shapes)."""

    serving = PolicyServing(path, {"threads": threads})

    def policy(observation: Mapping[str, np.ndarray], task: str) -> np.ndarray:
        inputs = {"observation": dict(observation)}
        serving.check("act", inputs, {})  # BadRequest (a ValueError) names the missing key or the wrong shape
        return np.asarray(next(iter(serving.run("act", inputs, {})))["actions"], np.float32)

    return policy


class PolicyServer:
    """``transport.AsyncInference`` over gRPC for one ``policy`` (see the module docstring)."""

    def __init__(self, policy: Policy, *, latency_s: float = 0.0, obs_queue_timeout_s: float = 2.0) -> None:
        self.policy, self.latency_s, self.obs_timeout = policy, float(latency_s), float(obs_queue_timeout_s)
        self.setup: dict[str, Any] | None = None
        self._latest: queue.Queue[dict[str, Any]] = queue.Queue(maxsize=1)
        self._lock = threading.Lock()
        self._server: Any = None
        self.served = 0

    # -- the service ------------------------------------------------------------------------------------------
    def _payload(self, data: bytes, context: Any) -> dict[str, Any]:
        import grpc

        try:
            return decode_payload(data)
        except ValueError as exc:
            context.abort(grpc.StatusCode.INVALID_ARGUMENT, f"{exc}; this server speaks msgpack: use "
                          "embagents.models.LeRobotPolicyClient (encoding='msgpack')")
            raise  # abort raises; this line is for the type checker

    def ready(self, request: Any, context: Any) -> Any:
        log.info("client %s ready", context.peer())
        with self._lock:
            self.setup = None
            while not self._latest.empty():
                self._latest.get_nowait()
        return messages()["Empty"]()

    def send_policy_instructions(self, request: Any, context: Any) -> Any:
        self.setup = self._payload(request.data, context)
        log.info("policy setup: %s, %s actions per chunk", self.setup.get("policy_type"),
                 self.setup.get("actions_per_chunk"))
        return messages()["Empty"]()

    def send_observations(self, request_iterator: Any, context: Any) -> Any:
        m = messages()
        buffer = io.BytesIO()
        for item in request_iterator:
            if item.transfer_state == m["TRANSFER_BEGIN"]:
                buffer = io.BytesIO()
            buffer.write(item.data)
            if item.transfer_state == m["TRANSFER_END"]:
                observation = self._payload(buffer.getvalue(), context)
                with self._lock:  # only the latest observation counts, as in LeRobot's server
                    if self._latest.full():
                        self._latest.get_nowait()
                    self._latest.put_nowait(observation)
                buffer = io.BytesIO()
        return m["Empty"]()

    def get_actions(self, request: Any, context: Any) -> Any:
        import grpc

        m = messages()
        start = time.monotonic()
        try:
            obs = self._latest.get(timeout=self.obs_timeout)
        except queue.Empty:
            return m["Actions"]()
        if self.setup is None:
            context.abort(grpc.StatusCode.FAILED_PRECONDITION, "no policy setup yet: send Ready and "
                          "SendPolicyInstructions first")
        try:
            actions = self.policy(obs.get("observation", {}), str(obs.get("task", "")))
        except (KeyError, ValueError) as exc:
            context.abort(grpc.StatusCode.INVALID_ARGUMENT, str(exc).strip("'\""))
        except Exception as exc:  # the policy failed: say so, keep serving
            log.exception("policy failed")
            context.abort(grpc.StatusCode.INTERNAL, f"the policy failed: {type(exc).__name__}: {exc}")
        wanted = int(self.setup.get("actions_per_chunk") or len(actions)) if self.setup else len(actions)
        actions = np.asarray(actions, np.float32)[:wanted]
        time.sleep(max(0.0, self.latency_s - (time.monotonic() - start)))
        self.served += 1
        return m["Actions"](data=encode_payload({"timestep": obs.get("timestep", 0), "actions": actions}))

    # -- lifecycle --------------------------------------------------------------------------------------------
    def start(self, address: str = "127.0.0.1:8080", workers: int = 4, *, tls: tuple[bytes, bytes] | None = None,
              token: str | None = None) -> int:
        """Serve on ``address`` (``host:port``; port 0 picks one); returns the port.

        ``tls``: (certificate, key), PEM: TLS instead of plaintext; ``token``: calls without
        ``authorization: Bearer TOKEN`` are refused (UNAUTHENTICATED). A token needs TLS.
        """
        if token and tls is None:
            raise ValueError("a token needs TLS (--tls-cert and --tls-key): over plaintext anyone on the way could read it")
        try:
            import grpc
        except ImportError as exc:
            raise ModuleNotFoundError("the policy server needs grpcio: pip install 'embagents[vla]'") from exc
        m = messages()

        def unary(fn: Callable[..., Any], request: str) -> Any:
            return grpc.unary_unary_rpc_method_handler(fn, request_deserializer=m[request].FromString,
                                                       response_serializer=lambda msg: msg.SerializeToString())

        handlers = {
            "Ready": unary(self.ready, "Empty"),
            "SendPolicyInstructions": unary(self.send_policy_instructions, "PolicySetup"),
            "GetActions": unary(self.get_actions, "Empty"),
            "SendObservations": grpc.stream_unary_rpc_method_handler(
                self.send_observations, request_deserializer=m["Observation"].FromString,
                response_serializer=lambda msg: msg.SerializeToString()),
        }
        interceptors = [_token_check(token)] if token else []
        server = grpc.server(futures.ThreadPoolExecutor(max_workers=workers), interceptors=interceptors)
        server.add_generic_rpc_handlers((grpc.method_handlers_generic_handler(SERVICE, handlers),))
        if tls is not None:
            port = server.add_secure_port(address, grpc.ssl_server_credentials([(tls[1], tls[0])]))
        else:
            port = server.add_insecure_port(address)
        if port == 0:
            raise OSError(f"cannot listen on {address} (in use, or not an address of this machine)")
        server.start()
        self._server = server
        return int(port)

    def wait(self) -> None:
        """Block until the server stops."""
        if self._server is not None:
            self._server.wait_for_termination()

    def stop(self, grace_s: float = 0.5) -> None:
        """Stop serving (waiting at most ``grace_s`` for calls under way)."""
        if self._server is not None:
            self._server.stop(grace_s).wait()
            self._server = None


def _token_check(token: str) -> Any:
    """A server interceptor that lets through only calls carrying ``token``."""
    import grpc

    class TokenCheck(grpc.ServerInterceptor):
        """Refuses calls that do not carry the token (compared in constant time)."""

        def __init__(self) -> None:
            self.expected = f"Bearer {token}".encode()

            def deny(request: Any, context: Any) -> Any:
                context.abort(grpc.StatusCode.UNAUTHENTICATED, "no valid token (authorization: Bearer ...)")

            self.deny_unary = grpc.unary_unary_rpc_method_handler(deny)
            self.deny_stream = grpc.stream_unary_rpc_method_handler(deny)

        def intercept_service(self, continuation: Any, details: Any) -> Any:
            got = dict(details.invocation_metadata or ()).get("authorization", "")
            if hmac.compare_digest(str(got).encode(), self.expected):
                return continuation(details)
            log.warning("refused a call of %s: no valid token", details.method)
            return self.deny_stream if details.method.endswith("/SendObservations") else self.deny_unary

    return TokenCheck()


def _read(path: str) -> bytes:
    with open(path, "rb") as f:
        return f.read()


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m embagents.models.lerobot_server --onnx POLICY.onnx [--host H] [--port P] [--latency-s S]``."""
    parser = argparse.ArgumentParser(prog="python -m embagents.models.lerobot_server", description=__doc__.split("\n")[0])
    parser.add_argument("--onnx", required=True, help="the ONNX policy file")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8080)
    parser.add_argument("--latency-s", type=float, default=0.0, help="answer no sooner than this (tests)")
    parser.add_argument("--tls-cert", metavar="PEM", help="serve TLS with this certificate (clients pass it as tls_ca)")
    parser.add_argument("--tls-key", metavar="PEM", help="the certificate's private key")
    parser.add_argument("--token-file", metavar="FILE", help="refuse calls without the token this file holds (needs TLS)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="lerobot_server: %(message)s")
    if bool(args.tls_cert) != bool(args.tls_key) or (args.token_file and not args.tls_cert):
        parser.error("pass --tls-cert and --tls-key together, and --token-file only with them")
    try:
        tls = (_read(args.tls_cert), _read(args.tls_key)) if args.tls_cert else None
        token = _read(args.token_file).decode().strip() if args.token_file else None
    except OSError as exc:
        parser.error(f"cannot read {exc.filename}: {exc.strerror}")
    if token == "":
        parser.error(f"{args.token_file} is empty: put the token in it")
    if tls is None and args.host not in ("127.0.0.1", "localhost", "::1"):
        log.warning("serving plaintext and unauthenticated on %s: anyone who can reach it can read observations and "
                    "send actions; pass --tls-cert, --tls-key and --token-file", args.host)
    server = PolicyServer(onnx_policy(args.onnx), latency_s=args.latency_s)
    port = server.start(f"{args.host}:{args.port}", tls=tls, token=token)
    print(f"serving {args.onnx} on {args.host}:{port}", flush=True)
    try:
        server.wait()
    except KeyboardInterrupt:
        server.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
