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
import contextlib
import logging
import os
import sys
import threading
from collections import deque
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

__all__ = ["SYSTEM_STOP", "Interrupted", "run", "run_system"]

log = logging.getLogger("embagents.supervise")

#: Publish anything on this topic to stop the whole system cleanly.
SYSTEM_STOP = "system_stop"
#: An import of system.py still running after this many seconds is said on stderr (it may never return).
IMPORT_NOTICE_S = 1.5


class Interrupted(Exception):
    """Ctrl-C before the system started: said in one line, not a traceback."""


class _EarlyLines(logging.Handler):
    """Holds the root's log records until the run's folder (and so ``logs/root.log``) exists."""

    def __init__(self, limit: int = 10_000) -> None:
        super().__init__()
        self.records: deque[logging.LogRecord] = deque(maxlen=limit)

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)

    def take(self) -> list[logging.LogRecord]:
        """Stop holding; the records held so far (before the file handler is added: none is written twice)."""
        logging.getLogger().removeHandler(self)
        records = list(self.records)
        self.records.clear()
        return records


def _load(path: str, quiet: bool) -> Any:
    """``load_system(path, lenient=True)``, saying on stderr when the import takes long."""
    from embagents.system import load_system

    name = os.path.basename(path)
    notice = threading.Timer(IMPORT_NOTICE_S, lambda: print(
        f"embagents: still importing {name}... (a top-level call that does not return? Ctrl-C stops)",
        file=sys.stderr, flush=True))
    notice.daemon = True
    if not quiet:
        notice.start()
    try:
        return load_system(path, lenient=True)  # every component's problems, as `embagents check` lists them
    finally:
        notice.cancel()


def run_system(path: str, dashboard: tuple[str, int] | None = None, *, quiet: bool = False,
               early: _EarlyLines | None = None) -> int:
    """Run the system in ``path`` under supervision until a stop; return the exit code.

    ``dashboard``: ``(host, port)`` to serve the dashboard on (:mod:`embagents.tools.dashboard`).
    ``quiet``: only warnings and errors on stderr (the actors' log files keep every line).
    ``early``: the root's log lines so far, written into ``logs/root.log`` once the run has its folder.
    """
    from actors import ActorSystem
    from embagents.check import check_system, errors
    from embagents.system import counted
    from supervisor.run import serve

    try:
        system = _load(path, quiet)
    except KeyboardInterrupt:
        raise Interrupted(f"stopped (Ctrl-C) while importing {path}; nothing was started") from None
    path = os.path.abspath(path)
    try:
        problems = check_system(system)
        for p in problems:
            print(p, file=sys.stderr)
        if errors(problems):
            print(f"{path}: {counted(len(errors(problems)), 'error')}; not starting", file=sys.stderr)
            return 1
        remember_system(path, system)  # forked actor processes find it in memory
        resolved = {m.name: m.resolve() for m in models_of(system)}  # downloads (with progress) happen here, once
        spec = build_spec(system, path, resolved)
    except KeyboardInterrupt:
        raise Interrupted("stopped (Ctrl-C) while checking the system and preparing its models; "
                          "nothing was started") from None

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
        running = (f"system {system.name!r} running ({counted(len(system.components), 'component')}, "
                   f"{managers}{counted(len(resolved), 'model')}); Ctrl-C or `embagents stop` stops it")
        held = early.take() if early is not None else []  # the start-up lines, logged before the folder existed
        with contextlib.suppress(OSError):  # a log file is a help, not a condition to run
            handler = add_log_file(asys.run_dir, "root")  # `embagents logs root`
            for record in held:
                handler.handle(record)
            handler.handle(log.makeRecord(log.name, logging.INFO, __file__, 0, running, (), None))  # the file only
        if not quiet:
            print(f"embagents: {running}", file=sys.stderr, flush=True)

    dashboards: list[Any] = []
    actors = ActorSystem(stderr_level=logging.WARNING if quiet else logging.NOTSET)
    try:
        return serve(spec, system_name=system.name, on_ready=on_ready, system=actors)
    finally:
        for d in dashboards:
            if d is not None:
                d.stop()
        actors.shutdown()


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
    quiet = getattr(args, "quiet", False)
    configure_logging("supervise", logging.DEBUG if args.verbose else logging.INFO,
                      logging.WARNING if quiet else logging.NOTSET)
    early = _EarlyLines()
    logging.getLogger().addHandler(early)
    try:
        dashboard = (args.dashboard_host, args.dashboard_port) if getattr(args, "dashboard", False) else None
        return run_system(args.system, dashboard, quiet=quiet, early=early)
    except Interrupted as exc:
        print(f"embagents supervise: {exc}", file=sys.stderr)
        return 130
    except Exception as exc:  # a clear one-line error, not a traceback, for bad input
        from actors import UnsafeFolder
        from embagents.system import SystemFileError
        from embagents.wheelfiles import WheelFileError

        # ConnectionError: a model hub or PyPI out of reach (the message names the way around it)
        if isinstance(exc, (SystemFileError, FileNotFoundError, ValueError, ConnectionError, WheelFileError, UnsafeFolder)):
            print(f"embagents supervise: {exc}", file=sys.stderr)
            return 1
        raise
    finally:
        logging.getLogger().removeHandler(early)
