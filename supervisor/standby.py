"""Warm standbys: a second, spawned process per expensive actor that takes over at once.

An actor child with ``standby=True`` (see :class:`~supervisor.spec.ChildSpec`)
has, besides its active incarnation, a standby: a process started by
:mod:`actors.spawn` (a fresh interpreter, so it may initialise CUDA) that
built the actor, ran its ``on_standby()`` (import the framework, load the
model) and waits, with no mailbox, topics or journal of its own. When the
active incarnation dies or is restarted, the supervisor's next start of the
child adopts the standby instead of starting a process
(:meth:`actors.ActorSystem.take_over`): it binds the actor's mailbox (senders
re-send what the dead one had not acknowledged: at-least-once, as after any
restart), restores the last snapshot before ``on_start``, replays the
lifecycle (whose ``on_configure`` finds the work done) and reports ready;
meanwhile a new standby is prepared in the background. A standby still in
``on_standby()`` when it is needed takes over as soon as it is done (still
sooner than a fresh start). The cost: twice the actor's memory.

A standby that dies is started again after a delay that doubles per failure
(0.5 s up to 30 s, reset once one gets ready), so a broken ``on_standby``
cannot spin. Stopping the child (or its supervisor) kills its standby:
it holds nothing that could be lost.

Events: ``standby_ready`` (child, pid, prepare_s) and ``standby_lost``
(child, pid, exit_code, detail); ``restarted`` says ``standby=True`` when a
standby took over.

Example::

    ChildSpec("detector", (Detector, ("yolo",)), lifecycle="active", standby=True)
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import time
from typing import TYPE_CHECKING

from actors import ProcessInfo

if TYPE_CHECKING:
    from supervisor.spec import ChildSpec
    from supervisor.tree import Tree

__all__ = ["Standby"]

log = logging.getLogger("supervisor.standby")

_FIRST_DELAY_S = 0.5
_MAX_DELAY_S = 30.0


class Standby:
    """The warm standby of one actor child (root IO thread only)."""

    def __init__(self, tree: Tree, spec: ChildSpec, path: str) -> None:
        self.tree = tree
        self.spec = spec
        self.path = path
        self.info: ProcessInfo | None = None
        self.stopped = False
        self.fails = 0
        self.timer: int | None = None

    @property
    def state(self) -> str | None:
        """"ready", "preparing", or None (none at the moment)."""
        if self.info is None:
            return None
        return "ready" if self.info.standing_by.is_set() else "preparing"

    def prepare(self) -> None:
        """Start a standby unless one is alive (or on its way)."""
        if self.stopped or self.info is not None or self.timer is not None:
            return
        from supervisor.procs import process_spec

        self.info = self.tree.system.start_process(process_spec(self.tree, self.spec), standby=True)

    def take(self) -> ProcessInfo | None:
        """Hand over the live standby (ready or still preparing), or None; a new one follows later."""
        info = self.info
        if info is None or info.exited.is_set() or not info.standby:
            return None
        self.info = None
        return info

    def stop(self) -> None:
        """Kill the standby and prepare no other (the child stops)."""
        self.stopped = True
        if self.timer is not None:
            self.tree.loop.cancel(self.timer)
            self.timer = None
        info, self.info = self.info, None
        if info is not None and info.pid is not None and not info.exited.is_set():
            with contextlib.suppress(ProcessLookupError):
                os.kill(info.pid, signal.SIGKILL)  # it has no mailbox or journal: nothing to lose

    # -- called by the tree's listeners --------------------------------------
    def on_note(self, kind: str, pid: int) -> None:
        info = self.info
        if kind == "standby" and info is not None and info.pid == pid:
            self.fails = 0
            self.tree.events.emit("standby_ready", supervisor=self.path, child=self.spec.id, pid=pid,
                                  prepare_s=round(time.monotonic() - info.started_at, 3))

    def on_exit(self, info: ProcessInfo) -> None:
        if info is not self.info:
            return
        self.info = None
        if self.stopped:
            return
        self.tree.events.emit("standby_lost", supervisor=self.path, child=self.spec.id, pid=info.pid,
                              exit_code=info.exit_code, detail=info.failure)
        delay = min(_MAX_DELAY_S, _FIRST_DELAY_S * 2 ** self.fails)
        self.fails += 1

        def again() -> None:
            self.timer = None
            self.prepare()

        self.timer = self.tree.loop.call_later(delay, again)
