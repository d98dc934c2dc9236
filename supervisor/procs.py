"""Incarnations: one run of a child, from its start to its exit.

A supervisor sees every kind of child (actor process, external command,
nested supervisor) through the same small interface: ``start()``, a
``ready`` future (True once it serves, False if it ended first), an
``exited`` future (its :class:`~supervisor.exits.Exit`), ``stop()`` (the
polite request: SIGTERM, on which an actor runs ``on_stop``) and ``kill()``
(SIGKILL). This module has the base class and the actor process; see
:mod:`supervisor.command` for external commands.

Exits come from the fork server's SIGCHLD path (a spawned process's: its
pidfd) through ``system.exit_listeners`` (no polling); "ready" comes from the actor's own
note to the root once ``on_start`` (and the lifecycle replay) is done; a
failed start, or a told message that raised, ends the process with status 1
after its "failed" note (:func:`actors.child.child_main` sends both).

Example::

    inc = ActorProcess(tree, spec, "root", tree.journal(spec.id))   # on the root IO thread
    inc.start()
    inc.ready.add_done_callback(lambda f: print("serving" if f.result() else "failed"))
"""

from __future__ import annotations

import contextlib
import os
import signal
import time
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from actors import extension_spec
from supervisor.aio import Future
from supervisor.exits import Exit, classify
from supervisor.lifecycle import Lifecycle
from supervisor.snapshot import Snapshots, keeps_snapshots

if TYPE_CHECKING:
    from actors import Journal, ProcessInfo
    from supervisor.spec import ChildSpec
    from supervisor.tree import Tree

__all__ = ["ActorProcess", "Incarnation", "Usage", "process_spec"]


class Usage:
    """Last resource sample of a process (filled by the tree's resource monitor)."""

    __slots__ = ("cpu_percent", "rss_mb", "at", "cpu_over_since")

    def __init__(self) -> None:
        self.cpu_percent = 0.0
        self.rss_mb = 0.0
        self.at = 0.0
        self.cpu_over_since: float | None = None


class Incarnation:
    """One run of a child; used on the root IO thread only."""

    kind = ""

    def __init__(self, tree: Tree, spec: ChildSpec, path: str) -> None:
        self.tree = tree
        self.spec = spec
        self.name = spec.id
        self.path = path  # the supervising supervisor's path, for events
        self.ready: Future[bool] = Future(tree.loop)
        self.exited: Future[Exit] = Future(tree.loop)
        self.started_at = time.monotonic()
        self.ready_at: float | None = None
        self.stopping = False  # its supervisor asked it to stop: not a crash
        self.cause: Exit | None = None  # why the supervisor killed it (hang, limit)
        self.usage = Usage()
        self.ps: Any = None  # psutil.Process, cached by the monitor

    @property
    def pid(self) -> int | None:
        raise NotImplementedError

    def start(self) -> None:
        raise NotImplementedError

    def _signal(self, sig: int) -> None:
        raise NotImplementedError

    def stop(self) -> None:
        """Ask it to stop cleanly (SIGTERM: an actor finishes its message and runs on_stop)."""
        self.stopping = True
        self._signal(signal.SIGTERM)

    def kill(self, cause: Exit | None = None) -> None:
        """Kill it now; ``cause`` replaces the exit reason (hang, limit)."""
        if cause is not None and self.cause is None:
            self.cause = cause
        self._signal(signal.SIGKILL)

    def _set_ready(self) -> None:
        if not self.ready.done() and not self.exited.done():
            self.ready_at = time.monotonic()
            self.ready.set_result(True)

    def _finish(self, code: int | None, failure: str | None = None) -> None:
        ex = classify(code, failure, requested=self.stopping)
        if self.cause is not None:
            ex = replace(self.cause, code=code)
        self.ready.set_result(False)  # no-op once ready
        self.exited.set_result(ex)


def process_spec(tree: Tree, s: ChildSpec) -> dict[str, Any]:
    """The process spec of actor child ``s`` (what the fork server or :mod:`actors.spawn` gets)."""
    st = s.start
    # Extension hooks run in this order (actors.extension): the snapshot is restored
    # before on_start, the lifecycle replayed after it; the child's own come last.
    extensions = []
    if keeps_snapshots(st.cls):
        extensions.append(extension_spec(Snapshots, {"interval": s.snapshot_interval}))
    extensions.append(extension_spec(Lifecycle, {"target": s.lifecycle}))
    extensions += [extension_spec(cls, config) for cls, config in s.extensions]
    return tree.system.make_spec(
        st.cls,
        s.id,
        st.args,
        st.kwargs,
        heartbeat=s.heartbeat or 1.0,
        poison_limit=s.poison_limit,
        nice=s.nice,
        cpu_affinity=list(s.cpu_affinity) if s.cpu_affinity else None,
        extensions=extensions,
    )


class ActorProcess(Incarnation):
    """An actor in its own process: forked by the run's fork server, spawned (``start_method="spawn"``),
    or a warm standby that takes over (:mod:`supervisor.standby`)."""

    kind = "actor"

    def __init__(self, tree: Tree, spec: ChildSpec, path: str, journal: Journal) -> None:
        super().__init__(tree, spec, path)
        self.journal = journal
        self.info: ProcessInfo | None = None
        self.expected_incarnation = 0
        self.failure: str | None = None
        self.from_standby = False  # a warm standby took over as this incarnation

    @property
    def pid(self) -> int | None:
        return None if self.info is None else self.info.pid

    def process_spec(self) -> dict[str, Any]:
        return process_spec(self.tree, self.spec)

    def start(self) -> None:
        # A ready note names the incarnation: a late note from a dead predecessor is ignored.
        self.expected_incarnation = self.journal.incarnation + 1
        self.tree.procs[self.name] = self
        self.started_at = time.monotonic()
        standby = self.tree.standbys.get(self.name) if self.spec.standby else None
        info = standby.take() if standby is not None else None
        if info is not None:  # the warm standby becomes this incarnation (supervisor.standby)
            self.from_standby = True
            self.info = info
            self.tree.system.take_over(info)
            return
        self.info = self.tree.system.start_process(self.process_spec(), method=self.spec.start_method)

    # -- called by the tree's listeners -------------------------------------
    def on_note(self, kind: str, pid: int, rest: list[Any]) -> None:
        info = self.info
        if info is None or self.exited.done():
            return
        mine = info.pid == pid or (info.pid is None and rest and rest[0] == self.expected_incarnation)
        if not mine:
            return
        if kind == "ready":
            self._ready_once_pid_known()
        elif kind == "failed" and rest:
            self.failure = str(rest[0])

    def _ready_once_pid_known(self) -> None:
        # The ready note can overtake the fork server's "spawned" note (another socket):
        # report ready with its pid, a moment later.
        if self.exited.done() or self.info is None:
            return
        if self.info.pid is None:
            self.tree.loop.call_later(0.0005, self._ready_once_pid_known)
            return
        self._set_ready()

    def on_exit(self, info: ProcessInfo) -> None:
        if info is not self.info:
            return
        if self.tree.procs.get(self.name) is self:
            del self.tree.procs[self.name]
        self._finish(info.exit_code, self.failure or info.failure)

    # -- signals -------------------------------------------------------------
    def _signal(self, sig: int, deadline: float | None = None) -> None:
        if self.exited.done():
            return
        pid = self.pid
        if pid is None:  # forked but the fork server's note is still on its way
            deadline = deadline or time.monotonic() + 5.0
            if time.monotonic() < deadline:
                self.tree.loop.call_later(0.001, lambda: self._signal(sig, deadline))
            return
        # The root may signal its grandchildren directly: one syscall, no hop.
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, sig)

