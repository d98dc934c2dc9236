"""``embagents supervise system.py``: load, check, and run a System until stopped.

The System file is imported first (so every class it uses is loaded before
the fork server forks), checked, and then each declared model gets a model
actor and each component a component actor, started in order. Ctrl-C,
SIGTERM, ``embagents stop``, or any message published on the
``system_stop`` topic stops everything in reverse order; the exit code is 0.

Ready before publishing: a component with subscribers declared for its
outputs (:func:`embagents.supervision.wiring`) starts inactive. Once the
tree has started, :class:`Activation` activates each when those subscribers
are connected (their subscription is in the topic's folder, so its first
publish reaches them) and active, subscribers first, so a keep-all topic
loses nothing at startup whatever the list order. A subscriber that is not
there after ``--wait-subscribers`` seconds is warned about by name and the
component is activated anyway. Then the run is ready: the announcement line
says so, ``--ready-file PATH`` is written, and ``embagents status
--wait-ready`` returns.

Example::

    $ embagents supervise examples/chat.py --ready-file /tmp/chat.ready &
    $ embagents status --wait-ready 60
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import sys
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from actors import ActorSystem, UnsafeFolder
from actors.child import add_log_file, configure_logging
from actors.topics import Subscription, subscriber_pids
from embagents.check import check_system, errors
from embagents.models import models_of
from embagents.models.files.wheels import WheelFileError
from embagents.requests import SUPERVISOR_REQUESTS, SupervisorRequest
from embagents.supervision import build_spec, wiring
from embagents.system import (
    SYSTEM_STOP,
    System,
    SystemFileError,
    counted,
    load_system,
    remember_system,
)
from embagents.tools.call import call_command
from embagents.tools.dashboard import Dashboard, DashboardError
from embagents.tools.publish import publish_command
from embagents.tools.root import install as install_tools
from embagents.tools.webguard import exposed_warning
from supervisor import Tree
from supervisor.client import request
from supervisor.lifecycle import ACTIVE, transition
from supervisor.rootio import on_root
from supervisor.run import serve

__all__ = ["SUBSCRIBER_WAIT_S", "Activation", "Interrupted", "arguments", "run", "run_system"]

log = logging.getLogger("embagents.supervise")

#: An import of system.py still running after this many seconds is said on stderr (it may never return).
IMPORT_NOTICE_S = 1.5
#: The longest a component waits for its subscribers before it is activated anyway (with a warning).
SUBSCRIBER_WAIT_S = 30.0


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
               early: _EarlyLines | None = None, ready_file: str | None = None,
               wait_subscribers: float = SUBSCRIBER_WAIT_S) -> int:
    """Run the system in ``path`` under supervision until a stop; return the exit code.

    ``dashboard``: ``(host, port)`` to serve the dashboard on (:mod:`embagents.tools.dashboard`).
    ``quiet``: only warnings and errors on stderr (the actors' log files keep every line).
    ``early``: the root's log lines so far, written into ``logs/root.log`` once the run has its folder.
    ``ready_file``: written once every component is active (removed first, and when the run ends).
    ``wait_subscribers``: see :class:`Activation`.
    """

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
        waits = wiring(system)  # these start inactive: Activation activates them once their subscribers are up
        spec = build_spec(system, path, resolved, activate_later=waits)
    except KeyboardInterrupt:
        raise Interrupted("stopped (Ctrl-C) while checking the system and preparing its models; "
                          "nothing was started") from None
    if ready_file:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(ready_file)  # a script waiting on it must not see an earlier run's
    activations: list[Activation] = []

    def on_ready(sup: Any, control: Any) -> None:
        asys = sup.system
        control.hold_ready()  # ready once every component is active (Activation)
        requests = _SupervisorRequests(sup)

        def stop_requested(_msg: Any) -> None:
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
                   f"{managers}{counted(len(resolved), 'model')})")
        held = early.take() if early is not None else []  # the start-up lines, logged before the folder existed
        handler: logging.Handler | None = None
        with contextlib.suppress(OSError):  # a log file is a help, not a condition to run
            handler = add_log_file(asys.run_dir, "root")  # `embagents logs root`
            for record in held:
                handler.handle(record)
            handler.handle(log.makeRecord(log.name, logging.INFO, __file__, 0, running + "; activating", (), None))

        def ready() -> None:
            if ready_file:
                _write_ready_file(ready_file, asys, system.name)
            control.mark_ready()
            line = f"{running}, ready; Ctrl-C or `embagents stop` stops it"
            if handler is not None:
                handler.handle(log.makeRecord(log.name, logging.INFO, __file__, 0, line, (), None))  # the file only
            if not quiet:
                print(f"embagents: {line}", file=sys.stderr, flush=True)

        activations.append(Activation(sup, system, waits, wait_subscribers, ready).start())

    dashboards: list[Any] = []
    actors = ActorSystem(stderr_level=logging.WARNING if quiet else logging.NOTSET)
    try:
        return serve(spec, system_name=system.name, on_ready=on_ready, system=actors)
    finally:
        for a in activations:
            a.stop()
        for d in dashboards:
            if d is not None:
                d.stop()
        actors.shutdown()
        if ready_file and activations and activations[0].done:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(ready_file)


def _write_ready_file(path: str, asys: Any, name: str) -> None:
    """Write ``path`` at once (a reader never sees half of it): the run's id, folder, system and pid."""
    folder = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=".ready-", dir=folder)
    with os.fdopen(fd, "w") as f:
        json.dump({"run_id": asys.run_id, "run_dir": asys.run_dir, "system": name, "pid": os.getpid(),
                   "ready_at": time.time()}, f)
    os.replace(tmp, path)


class Activation:
    """Activates the components that wait for their subscribers, then calls ``on_ready`` (its own thread).

    ``waits`` is :func:`embagents.supervision.wiring`: component -> {output
    topic: declared subscribers}. A component is activated once each of its
    subscribers runs, has its subscription in the topic's folder
    (:func:`actors.topics.subscriber_pids`: the component's first publish
    reaches it) and, if it is a component, is active itself, unless it feeds
    the waiting one back (a cycle: then being subscribed is enough). Every
    child subscribes in ``on_start``, before the tree goes on, so after the
    start this normally holds at once, subscribers first. The thread wakes on
    the supervisor's started/restarted events (and at most every 0.5 s while
    something is missing: a subscription made later); after ``timeout`` s it
    activates the component anyway with a warning naming what is missing.
    A failed activation (``on_activate`` raised) stops the run, as a failed
    start does.
    """

    def __init__(self, sup: Any, system: System, waits: dict[str, dict[str, tuple[str, ...]]], timeout: float,
                 on_ready: Callable[[], None]) -> None:
        self.sup, self.asys, self.waits, self.timeout, self.on_ready = sup, sup.system, waits, timeout, on_ready
        self.components = {str(c.name) for c in system.components}
        self.pending = [str(c.name) for c in system.components if str(c.name) in waits]  # list order
        self.reach = _reach({c: {s for who in t.values() for s in who if s in waits} for c, t in waits.items()})
        self.changed = threading.Event()
        self.stopped = False
        self.done = False
        self._thread = threading.Thread(target=self._run, name="embagents-activate", daemon=True)

    def start(self) -> Activation:
        events = Tree.of(self.asys).events
        on_root(self.asys, lambda: events.listeners.append(self._on_event))
        self._thread.start()
        return self

    def stop(self) -> None:
        self.stopped = True
        self.changed.set()
        if self._thread is not threading.current_thread():
            self._thread.join(5)

    def _on_event(self, rec: dict[str, Any]) -> None:
        if rec.get("event") in ("started", "restarted"):
            self.changed.set()

    def _states(self) -> tuple[dict[str, Any], dict[str, int]]:
        """Each child's pid (an int when it runs) and each component's lifecycle state (its journal)."""

        tree = Tree.of(self.asys)
        pids = {c.id: c.pid for c in self.sup.which_children()}
        names = [n for n in self.components if n in pids]
        return pids, on_root(self.asys, lambda: {n: tree.journal(n).state() for n in names})

    def _missing(self, name: str, pids: dict[str, Any], states: dict[str, int]) -> list[str]:
        missing = []
        for topic, subscribers in self.waits[name].items():
            there = subscriber_pids(self.asys.run_dir, topic)
            for s in subscribers:
                pid = pids.get(s)
                if not isinstance(pid, int):
                    missing.append(f"{s!r} (not running)")
                elif pid not in there:
                    missing.append(f"{s!r} (not subscribed to {topic!r})")
                elif s in self.components and states.get(s) != ACTIVE and name not in self.reach.get(s, ()):
                    missing.append(f"{s!r} (not active)")
        return list(dict.fromkeys(missing))

    def _run(self) -> None:
        deadline = time.monotonic() + self.timeout
        try:
            while self.pending and not self.stopped:
                self.changed.clear()
                pids, states = self._states()
                progress = False
                for name in list(self.pending):
                    if not isinstance(pids.get(name), int):
                        continue  # itself restarting: it comes back inactive, and is activated then
                    if states.get(name) == ACTIVE:
                        self.pending.remove(name)  # activated meanwhile (the dashboard, `embagents` tools)
                        continue
                    missing = self._missing(name, pids, states)
                    if missing and time.monotonic() < deadline:
                        continue
                    if missing:
                        log.warning("component %r: activated without waiting longer than %g s for %s: what it "
                                    "publishes before they are up is lost", name, self.timeout, ", ".join(missing))
                    try:
                        transition(self.asys, name, "activate", timeout=60.0)
                    except Exception as exc:
                        if self.stopped or not self.sup.running:
                            return
                        if not isinstance(self._states()[0].get(name), int):
                            continue  # it died meanwhile: its restart comes back inactive
                        log.error("component %r could not be activated: %s; the run stops", name, exc)
                        self.sup.stop()
                        return
                    self.pending.remove(name)
                    states[name] = ACTIVE
                    progress = True
                    log.info("activated %s: %s", name, "; ".join(
                        f"{', '.join(who)} subscribed to {topic}" for topic, who in self.waits[name].items()))
                if self.pending and not progress:
                    self.changed.wait(max(0.01, min(0.5, deadline - time.monotonic())))
        except Exception:
            if self.stopped or not self.sup.running:
                return  # the run is stopping under us
            raise
        if not self.stopped:
            self.done = True
            self.on_ready()


def _reach(edges: dict[str, set[str]]) -> dict[str, set[str]]:
    """Every node each node leads to (directly or not) along ``edges``.

    >>> _reach({"a": {"b"}, "b": {"a"}, "c": {"a"}})["c"] == {"a", "b"}
    True
    """
    out: dict[str, set[str]] = {}
    for start in edges:
        seen: set[str] = set()
        todo = list(edges[start])
        while todo:
            n = todo.pop()
            if n not in seen:
                seen.add(n)
                todo.extend(edges.get(n, ()))
        out[start] = seen
    return out


def _start_dashboard(sup: Any, control: Any, system: System, topics: Any, where: tuple[str, int]) -> Any:
    """The running dashboard, or None (said on stderr) if it cannot start: the system runs on without it."""

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


def arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("system", help="path of the system.py file")
    loud = parser.add_mutually_exclusive_group()
    loud.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    loud.add_argument("-q", "--quiet", action="store_true",
                      help="only warnings and errors on stderr (the answers are on stdout; `embagents logs` has the rest)")
    parser.add_argument("--offline", action="store_true",
                        help="embagents.compat recipes: replace model servers by the offline default models")
    parser.add_argument("--dashboard", action="store_true", help="serve the dashboard page and its JSON/WebSocket API")
    parser.add_argument("--dashboard-host", default="127.0.0.1", help="the dashboard's address (default: this machine only)")
    parser.add_argument("--dashboard-port", type=int, default=8420, help="the dashboard's port (default 8420)")
    parser.add_argument("--ready-file", metavar="PATH",
                        help="write PATH once every component is active (removed first, and at the end of the run)")
    parser.add_argument("--wait-subscribers", type=float, default=30.0, metavar="SECONDS",
                        help="the longest a component waits for the subscribers of its outputs before it is "
                             "activated anyway, with a warning (default 30)")


def run(args: argparse.Namespace) -> int:
    quiet = getattr(args, "quiet", False)
    configure_logging("supervise", logging.DEBUG if args.verbose else logging.INFO,
                      logging.WARNING if quiet else logging.NOTSET)
    early = _EarlyLines()
    logging.getLogger().addHandler(early)
    if getattr(args, "offline", False):
        os.environ["EMBAGENTS_OFFLINE"] = "1"  # embagents.compat's clients: servers -> offline defaults (children too)
    try:
        dashboard = (args.dashboard_host, args.dashboard_port) if getattr(args, "dashboard", False) else None
        return run_system(args.system, dashboard, quiet=quiet, early=early,
                          ready_file=getattr(args, "ready_file", None),
                          wait_subscribers=getattr(args, "wait_subscribers", SUBSCRIBER_WAIT_S))
    except Interrupted as exc:
        print(f"embagents supervise: {exc}", file=sys.stderr)
        return 130
    except Exception as exc:  # a clear one-line error, not a traceback, for bad input

        # ConnectionError: a model hub or PyPI out of reach (the message names the way around it)
        if isinstance(exc, (SystemFileError, FileNotFoundError, ValueError, ConnectionError, WheelFileError, UnsafeFolder)):
            print(f"embagents supervise: {exc}", file=sys.stderr)
            return 1
        raise
    finally:
        logging.getLogger().removeHandler(early)
