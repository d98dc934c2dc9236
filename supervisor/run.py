"""Run a supervision tree until it is told to stop: what ``embagents supervise`` calls.

:func:`serve` starts the root supervisor (children in order), opens the
control endpoint and the discovery file, then waits for one of: SIGINT or
SIGTERM, a ``stop`` control request, or the root supervisor giving up. It
then stops every child in reverse order, closes the endpoint and (if it
created it) shuts the actor system down. The return value is the process
exit status: 0 after a requested stop, 1 if the tree could not start or
gave up.

Example::

    import sys
    spec = SupervisorSpec(children=[ChildSpec("echo", Echo)])
    sys.exit(serve(spec, system_name="demo"))
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
from collections.abc import Callable
from typing import Any

from actors import ActorSystem
from supervisor.control import ControlServer
from supervisor.errors import StartError
from supervisor.rootio import on_root
from supervisor.spec import SupervisorSpec
from supervisor.supervisor import Supervisor, start_supervisor
from supervisor.tree import Tree

__all__ = ["serve"]

log = logging.getLogger("supervisor.run")


def serve(
    spec: SupervisorSpec,
    *,
    system_name: str,
    name: str = "root",
    system: ActorSystem | None = None,
    handle_signals: bool = True,
    on_ready: Callable[[Supervisor, ControlServer], Any] | None = None,
    stop_timeout: float | None = None,
) -> int:
    """Supervise ``spec`` until stopped; returns the exit status (see the module docs)."""
    own = system is None
    if system is None:
        system = ActorSystem()
    stop = threading.Event()
    requested = threading.Event()

    def ask_stop(*_: Any) -> None:
        requested.set()
        stop.set()

    old: dict[int, Any] = {}
    if handle_signals and threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.signal(sig, ask_stop)
    control = None
    try:
        try:
            sup = start_supervisor(system, spec, name)
        except StartError as exc:
            log.error("the supervision tree could not start: %s", exc)
            return 1
        on_root(system, lambda: sup.exited.add_done_callback(lambda _: stop.set()))
        control = ControlServer(system, system_name, on_stop=ask_stop)
        log.info("supervising %s (run %s, %s)", system_name, system.run_id, system.run_dir)
        if on_ready is not None:
            on_ready(sup, control)
        if not control.ready_held:  # else on_ready's layer says when (ControlServer.mark_ready)
            control.mark_ready()
        while not stop.wait(1.0):  # a timeout keeps Ctrl-C responsive on every platform
            pass
        gave_up = not requested.is_set()
        ex = sup.stop(stop_timeout)
        if gave_up:
            log.error("the root supervisor gave up (%s); the run ends", ex)
        return 1 if gave_up else 0
    finally:
        if control is not None:
            control.close()
        Tree.of(system).close()
        if own:
            system.shutdown()
        for signum, handler in old.items():
            with contextlib.suppress(ValueError, TypeError):
                signal.signal(signum, handler)
