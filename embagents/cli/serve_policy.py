"""``embagents serve-policy POLICY --bind ws://HOST:PORT``: a policy over openpi's WebSocket protocol.

Runs one supervised policy model actor (restarted by the supervisor as
``embagents supervise`` does; ``embagents status`` and ``stop`` reach it)
that loads POLICY and answers openpi clients
(:func:`~embagents.models.openpi_server.start_openpi`)
(``openpi_client.websocket_client_policy``, starVLA, IsaacLab-Arena, our
:class:`~embagents.models.openpi.OpenPIPolicyClient`). POLICY is:

- an ONNX policy file (``reach.onnx``: inputs named by observation keys);
- ``SYSTEM_PY:NAME``: the ``PolicyModel`` named NAME that a system.py declares.

On loopback ``ws://127.0.0.1:PORT`` needs nothing more. Beyond it, pass
``--api-key-file`` (clients send ``Authorization: Api-Key KEY``; checked in
constant time) and/or bind ``wss://`` with ``--tls-cert``/``--tls-key``:
a plain, keyless bind beyond loopback is refused. ``--delay-ms`` adds a fixed
latency to each inference (a GPU policy's, for tests and the bench).

Example::

    $ embagents serve-policy reach.onnx --bind ws://127.0.0.1:8000
    $ curl http://127.0.0.1:8000/healthz
    OK
"""

from __future__ import annotations

import argparse
import logging
import os
import re
import sys
from typing import Any

from actors.child import configure_logging
from embagents.cli.serve_model import model_of
from embagents.models.actor import ModelActor
from embagents.models.openpi_server import check_bind, read_api_key
from embagents.models.policy import PolicyModel
from embagents.supervision import MODEL_HEARTBEAT_S
from supervisor import ChildSpec, SupervisorSpec
from supervisor.run import serve

__all__ = ["policy_of", "run", "arguments", "serve_policy_spec"]


def policy_of(spec: str) -> Any:
    """The :class:`~embagents.models.policy.PolicyModel` POLICY names (an .onnx file or SYSTEM_PY:NAME)."""

    if spec.endswith(".onnx"):
        stem = re.sub(r"[^A-Za-z0-9_]", "_", os.path.splitext(os.path.basename(spec))[0]) or "policy"
        return PolicyModel(name=stem, local_model_path=spec)
    path, sep, _ = spec.rpartition(":")
    if not (sep and path.endswith(".py")):
        raise ValueError(f"POLICY {spec!r} is not known: pass an ONNX policy file (.onnx) or SYSTEM_PY:NAME "
                         "(a PolicyModel a system.py declares)")

    model = model_of(spec)
    if model.kind != "policy":
        raise ValueError(f"{spec} is a {model.kind} model, not a policy; name a PolicyModel")
    return model


def serve_policy_spec(model: Any, path: str, bind: str, *, api_key_file: str | None = None,
                      tls_cert: str | None = None, tls_key: str | None = None, delay_ms: float = 0.0) -> Any:
    """The supervision tree: one policy server actor serving ``model``'s file at ``path`` on ``bind``."""

    check_bind(bind, api_key=bool(api_key_file), tls=bool(tls_cert))
    openpi = {"bind": bind, "api_key_file": api_key_file, "tls_cert": tls_cert, "tls_key": tls_key,
              "delay_ms": float(delay_ms), "name": model.name}
    args = (model.kind, path, {**model.options(), "openpi": openpi}, model.warmup)
    child = ChildSpec(model.name, (ModelActor, args), heartbeat=MODEL_HEARTBEAT_S, start_timeout=600)
    return SupervisorSpec(children=[child], intensity=5, period=30.0)


def arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("policy", metavar="POLICY", help="an ONNX policy file, or SYSTEM_PY:NAME (a PolicyModel)")
    parser.add_argument("--bind", required=True, metavar="ws://HOST:PORT",
                        help="where openpi clients connect (wss:// with --tls-cert/--tls-key)")
    parser.add_argument("--api-key-file", metavar="FILE", help="a file (mode 600) holding the key clients must send")
    parser.add_argument("--tls-cert", metavar="CERT.pem", help="the server's certificate (for wss://)")
    parser.add_argument("--tls-key", metavar="KEY.pem", help="its private key (for wss://)")
    parser.add_argument("--delay-ms", type=float, default=0.0, metavar="MS", help="added to each inference (tests)")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")


def run(args: argparse.Namespace) -> int:
    configure_logging("serve-policy", logging.DEBUG if args.verbose else logging.INFO)
    try:
        if bool(args.tls_cert) != bool(args.tls_key):
            raise ValueError("--tls-cert and --tls-key go together (the certificate and its private key)")
        check_bind(args.bind, api_key=bool(args.api_key_file), tls=bool(args.tls_cert))
        key_file = os.path.abspath(args.api_key_file) if args.api_key_file else None
        if key_file:
            read_api_key(key_file)  # a bad file is named now, not after the actor failed to start
        tls = [os.path.abspath(p) if p else None for p in (args.tls_cert, args.tls_key)]
        for p in tls:
            if p and not os.path.isfile(p):
                raise ValueError(f"no such file: {p}")
        model = policy_of(args.policy)
        problem = model.file_problem()
        if problem:
            raise ValueError(problem)
        spec = serve_policy_spec(model, model.resolve(), args.bind, api_key_file=key_file, tls_cert=tls[0],
                                 tls_key=tls[1], delay_ms=args.delay_ms)
    except (ValueError, FileNotFoundError) as exc:
        print(f"embagents serve-policy: {exc}", file=sys.stderr)
        return 1

    def on_ready(_sup: Any, _control: Any) -> None:
        print(f"embagents: serving policy {model.name!r} over openpi's protocol on {args.bind}"
              f"{' (API key required)' if args.api_key_file else ''}; health: {args.bind.replace('ws', 'http', 1)}"
              "/healthz; Ctrl-C or `embagents stop` stops it", file=sys.stderr, flush=True)

    return serve(spec, system_name=f"serve-policy-{model.name}", on_ready=on_ready)
