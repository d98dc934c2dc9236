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
import sys
import threading
from typing import Any

from actors.child import add_log_file, configure_logging
from actors.topics import Subscription
from embagents.call import call_command
from embagents.models import models_of
from embagents.publish import publish_command
from embagents.runtime.component_actor import remember_system
from embagents.runtime.requests import SUPERVISOR_REQUESTS, SupervisorRequest
from embagents.supervision import build_spec
from embagents.tools.root import install as install_tools

__all__ = ["SYSTEM_STOP", "run", "run_system"]

log = logging.getLogger("embagents.supervise")

#: Publish anything on this topic to stop the whole system cleanly.
SYSTEM_STOP = "system_stop"
def run_system(path: str, dashboard: tuple[str, int] | None = None) -> int:
    """Run the system in ``path`` under supervision until a stop; return the exit code.

    ``dashboard``: ``(host, port)`` to serve the dashboard on (:mod:`embagents.tools.dashboard`).
    """
    from embagents.check import check_system, errors
    from embagents.system import counted, load_system
    from supervisor.run import serve

    system = load_system(path, lenient=True)  # every component's problems, as `embagents check` lists them
    path = os.path.abspath(path)
    problems = check_system(system)
    for p in problems:
        print(p, file=sys.stderr)
    if errors(problems):
        print(f"{path}: {counted(len(errors(problems)), 'error')}; not starting", file=sys.stderr)
        return 1
    remember_system(path, system)  # forked actor processes find it in memory
    resolved = {m.name: m.resolve() for m in models_of(system)}  # downloads (with progress) happen here, once
    spec = build_spec(system, path, resolved)

    def on_ready(sup: Any, control: Any) -> None:
        asys = sup.system
        requests = _SupervisorRequests(sup)

        def stop_requested(_msg: Any) -> None:
            from supervisor.client import request

            threading.Thread(target=request, args=(asys.run_dir, {"cmd": "stop"}, 10.0), daemon=True).start()

        asys.rt.on_client(lambda: (
            Subscription(asys.rt, asys.loop, SYSTEM_STOP, stop_requested, queue_size=1),
            Subscription(asys.rt, asys.loop, SUPERVISOR_REQUESTS, requests.on_request, queue_size=100, keep="all"),
        ))
        control.add_command("publish", publish_command(asys, system))  # `embagents publish TOPIC TEXT`
        control.add_command("call", call_command(asys, system))  # `embagents call COMPONENT METHOD ARGS`
        managers = f"{counted(len(system.managers), 'manager')}, " if system.managers else ""
        topics = install_tools(sup, control, system)  # `embagents topic list`, `embagents record`
        if dashboard is not None:
            dashboards.append(_start_dashboard(sup, control, system, topics, dashboard))
        add_log_file(asys.run_dir, "root")  # `embagents logs root`
        print(f"embagents: system {system.name!r} running ({counted(len(system.components), 'component')}, "
              f"{managers}{counted(len(resolved), 'model')}); Ctrl-C or `embagents stop` stops it", file=sys.stderr,
              flush=True)

    dashboards: list[Any] = []
    try:
        return serve(spec, system_name=system.name, on_ready=on_ready)
    finally:
        for d in dashboards:
            if d is not None:
                d.stop()


def _start_dashboard(sup: Any, control: Any, system: Any, topics: Any, where: tuple[str, int]) -> Any:
    """The running dashboard, or None (said on stderr) if it cannot start: the system runs on without it."""
    from embagents.tools.dashboard import Dashboard, DashboardError
    from embagents.tools.webguard import exposed_warning

    try:
        dash = Dashboard(sup, control, system, topics).start(*where)
    except DashboardError as exc:
        print(f"embagents supervise: {exc}; the system runs without it", file=sys.stderr, flush=True)
        return None
    print(f"embagents: dashboard on {dash.url}", file=sys.stderr, flush=True)  # the token: only its user sees it
    warning = exposed_warning("the dashboard", where[0], "--dashboard-host",
                              "whoever reaches it with its token controls the run, and the token crosses in clear")
    if warning:
        print(f"embagents: {warning}", file=sys.stderr, flush=True)
    return dash


class _SupervisorRequests:
    """Carries out start / stop / restart / give_up requests from events and fallbacks."""

    def __init__(self, sup: Any) -> None:
        self.sup = sup

    def on_request(self, req: SupervisorRequest) -> None:
        # Supervisor calls block and refuse the root IO thread: use a helper thread.
        threading.Thread(target=self._do, args=(req,), daemon=True).start()

    def _do(self, req: SupervisorRequest) -> None:
        kind, name = req.kind, req.component
        log.info("%s %s (%s)", kind, name, req.because)
        try:
            if kind in ("stop", "give_up"):
                self.sup.terminate_child(name)
            elif kind == "start":
                self.sup.restart_child(name)
            elif kind == "restart":
                self.sup.bounce(name)
        except Exception as exc:  # an action on a child that is not there: say so, go on
            log.error("%s %s failed: %s", kind, name, exc)


def run(args: argparse.Namespace) -> int:
    configure_logging("supervise", logging.DEBUG if args.verbose else logging.INFO)
    if getattr(args, "offline", False):
        os.environ["EMBAGENTS_OFFLINE"] = "1"  # embagents.compat's clients: servers -> offline defaults (children too)
    try:
        dashboard = (args.dashboard_host, args.dashboard_port) if getattr(args, "dashboard", False) else None
        return run_system(args.system, dashboard)
    except Exception as exc:  # a clear one-line error, not a traceback, for bad input
        from actors import UnsafeFolder
        from embagents.system import SystemFileError
        from embagents.wheelfiles import WheelFileError

        # ConnectionError: a model hub or PyPI out of reach (the message names the way around it)
        if isinstance(exc, (SystemFileError, FileNotFoundError, ValueError, ConnectionError, WheelFileError, UnsafeFolder)):
            print(f"embagents supervise: {exc}", file=sys.stderr)
            return 1
        raise
