"""``embagents supervise system.py``: load, check, and run a System until stopped.

The System file is imported first (so every class it uses is loaded before
the fork server forks), checked, and then each declared model gets a model
actor and each component a component actor, started in order. Ctrl-C,
SIGTERM, ``embagents stop``, or any message published on the
``system_stop`` topic stops everything in reverse order; the exit code is 0.

Example::

    $ embagents supervise examples/chat.py
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
import time
from typing import Any

from actors import ActorSystem
from actors.child import configure_logging
from actors.topics import Subscription
from embagents.models import LlamaModel, LocalModelClient
from embagents.runtime.component_actor import ComponentActor, remember_system
from embagents.runtime.events_actor import LIFECYCLE_TOPIC, EventsActor
from embagents.runtime.model_actor import LlamaModelActor

__all__ = ["SYSTEM_STOP", "add_arguments", "run", "run_system"]

log = logging.getLogger("embagents.supervise")

#: Publish anything on this topic to stop the whole system cleanly.
SYSTEM_STOP = "system_stop"


def _models_of(system: Any) -> list[LlamaModel]:
    """Every model the system declares or that a component's client refers to, once."""
    found: dict[str, LlamaModel] = {}
    for m in system.models:
        if isinstance(m, LlamaModel):
            found.setdefault(m.name, m)
    for c in system.components:
        for client in getattr(c, "clients", {}).values():
            if isinstance(client, LocalModelClient):
                model = client.model or found.get(client.name)
                if model is None:
                    raise ValueError(
                        f"component {c.name!r} uses model {client.name!r}, which the system does not declare: "
                        "pass the LlamaModel to LocalModelClient or to System(models=[...])"
                    )
                found.setdefault(model.name, model)
    return list(found.values())


def run_system(path: str, *, stop_event: threading.Event | None = None, heartbeat: float | None = 5.0) -> int:
    """Run the system in ``path`` until a stop; return the exit code."""
    from embagents.check import check_system
    from embagents.system import load_system

    path = os.path.abspath(path)
    system = load_system(path)
    problems = check_system(system)
    errors = [p for p in problems if getattr(p, "level", "error") == "error"]
    for p in problems:
        print(f"{getattr(p, 'level', 'error')}: {p.message}", file=sys.stderr)
    if errors:
        print(f"{path}: {len(errors)} problem(s); not starting (run `embagents check {path}`)", file=sys.stderr)
        return 1
    remember_system(path, system)
    models = _models_of(system)
    resolved = {m.name: m.resolve() for m in models}  # downloads (with progress) happen here, once
    stop = stop_event or threading.Event()
    asys = ActorSystem()
    try:
        for m in models:
            opts = {"n_ctx": m.n_ctx, "n_threads": m.n_threads, "seed": m.seed}
            log.info("starting model actor %s (%s)", m.name, resolved[m.name])
            asys.spawn(LlamaModelActor, m.name, resolved[m.name], opts, m.warmup, wait=600, heartbeat=None)
        for c in system.components:
            log.info("starting component %s", c.name)
            asys.spawn(ComponentActor, str(c.name), path, str(c.name), wait=120, heartbeat=heartbeat)
        if system.ros:
            from embagents.ros.bridge_actor import BRIDGE_NAME, RosBridgeActor

            asys.spawn(RosBridgeActor, BRIDGE_NAME, path, wait=60, heartbeat=heartbeat)
        if system.events or any(getattr(c, "fallback", None) for c in system.components):
            asys.spawn(EventsActor, "_events", path, wait=60, heartbeat=heartbeat)
        lifecycle = _Lifecycle(asys)
        asys.rt.on_client(lambda: (
            Subscription(asys.rt, asys.loop, SYSTEM_STOP, lambda _m: stop.set(), queue_size=1),
            Subscription(asys.rt, asys.loop, LIFECYCLE_TOPIC, lifecycle.on_request, queue_size=100, keep="all"),
        ))
        print(f"embagents: system {system.name!r} running ({len(system.components)} components, "
              f"{len(models)} models); Ctrl-C stops it", file=sys.stderr, flush=True)
        _wait(stop)
    finally:
        log.info("stopping")
        t0 = time.monotonic()
        asys.shutdown()
        log.info("stopped in %.2f s", time.monotonic() - t0)
    return 0


class _Lifecycle:
    """Carries out start / stop / restart / give_up requests from events and fallbacks."""

    def __init__(self, asys: ActorSystem) -> None:
        self.asys = asys
        self.specs: dict[str, dict[str, Any]] = {}

    def on_request(self, req: dict[str, Any]) -> None:
        # Runs on the root IO thread: do the blocking work on a helper thread.
        threading.Thread(target=self._do, args=(req,), daemon=True).start()

    def _do(self, req: dict[str, Any]) -> None:
        kind, name = req.get("kind"), req.get("component")
        asys = self.asys
        info = asys.procs.get(name)
        if info is not None:
            self.specs[name] = info.spec
        spec = self.specs.get(name)
        log.info("%s %s (%s)", kind, name, req.get("because", ""))
        if kind in ("stop", "give_up", "restart") and info is not None:
            asys.stop(name, unregister=False)
        if kind in ("start", "restart") and spec is not None:
            asys.wait_ready(asys.start_process(spec), 120)


def _wait(stop: threading.Event) -> None:
    if threading.current_thread() is threading.main_thread():
        prev = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            while not stop.wait(3600):
                pass
        finally:
            for s, h in prev.items():
                signal.signal(s, h)
    else:
        stop.wait()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("system", help="path of the system.py file")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")


def run(args: argparse.Namespace) -> int:
    configure_logging("supervise", logging.DEBUG if args.verbose else logging.INFO)
    try:
        return run_system(args.system)
    except Exception as exc:  # a clear one-line error, not a traceback, for bad input
        from embagents.system import SystemFileError

        if isinstance(exc, (SystemFileError, FileNotFoundError, ValueError)):
            print(f"embagents supervise: {exc}", file=sys.stderr)
            return 1
        raise
