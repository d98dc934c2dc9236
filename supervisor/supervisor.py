"""Supervisors: OTP's supervisor behaviour over actor processes, commands and nested supervisors.

A supervisor starts its children, watches them and restarts them by
policy. It is an object on the root IO thread (not a process of its own);
its children are processes (actors, external commands) or other
supervisors. The semantics are OTP's ``supervisor``; where they differ it
says so.

**Starting.** Children start in the order of the spec, each only after the
previous one is ready (an actor is ready once ``on_start`` returned and its
lifecycle state was restored; a command once it runs; a supervisor once all
its own children are ready). If a child fails to start (it exits first, or
is not ready within ``start_timeout``), the children already started are
stopped in reverse order and the supervisor fails to start
(:class:`~supervisor.errors.StartError`; in a nested supervisor this is a
failed start for its parent).

**Stopping.** A supervisor stops its children in reverse start order, each
fully (per its ``shutdown``) before the next; ``simple_one_for_one``
children are all stopped at once. Shutdown modes: seconds (SIGTERM, on
which an actor finishes its current message and runs ``on_stop``; SIGKILL
if it has not exited after that many seconds), ``"brutal_kill"`` (SIGKILL
at once) or ``"infinity"`` (SIGTERM, then wait as long as it takes; the
default for supervisors).

**Exits and restart types.** When a child exits on its own, its reason is
``normal`` (exit code 0), ``shutdown`` (SIGTERM), ``killed`` (a SIGKILL its
supervisor did not send) or ``error`` (any other code or signal, a hang, a
resource limit). Then:

- permanent: always restarted;
- transient: restarted unless the reason is normal or shutdown;
- temporary: never restarted; its spec is dropped.

A ``transient`` child that is not restarted keeps its spec (``which_children``
shows no pid) except under ``simple_one_for_one``, where it is dropped.

**Strategies.** Which children a restart involves:

- one_for_one: only the child that exited.
- one_for_all: all children: the others are stopped in reverse order
  (temporary ones are dropped, not restarted), then all are started in order,
  including ones that had been stopped or had ended normally.
- rest_for_one: the child that exited and every child after it in start
  order: those are stopped in reverse order and started again in order.
- simple_one_for_one: children are added at run time with
  ``start_child(*args)``, all from one template spec; restarts are per child.

**Restart intensity.** Each restart the supervisor decides on is recorded.
If more than ``intensity`` restarts happened within the last ``period``
seconds, the supervisor gives up: it stops all its children in reverse
order and exits with reason ``shutdown``; its parent handles that like any
child exit (so it restarts the supervisor only if that supervisor's own spec
is ``permanent``, and counts it against its own intensity). A root
supervisor that gives up ends the run. If a restart's start fails, the
supervisor retries (after handling whatever else is queued), and every
retry is a restart in the same accounting, so a child that can never start
exhausts the intensity instead of looping forever.

**Beyond OTP.** ``backoff`` delays each restart (the restart still counts
when decided); ``heartbeat`` kills a hung actor; ``max_rss_mb`` and
``max_cpu_percent`` kill a leaking one; both then count as an ``error``
exit (see :mod:`supervisor.health`).

**Calls.** ``start_child``, ``terminate_child``, ``restart_child`` and
``delete_child`` are queued behind whatever the supervisor is doing, as
calls to an OTP supervisor are; they block the calling thread until done
and must not be called from the root IO thread (use them from the main
thread, a control thread, a test).

Example::

    from actors import ActorSystem
    system = ActorSystem()
    sup = start_supervisor(system, SupervisorSpec(
        strategy="one_for_one", intensity=3, period=10,
        children=[ChildSpec("echo", Echo), ChildSpec("cam", Command(["camera-sdk"]))]))
    [c.id for c in sup.which_children()]     # ['echo', 'cam']
    sup.stop()                               # stops cam, then echo
"""

from __future__ import annotations

import functools
import itertools
import logging
import os
import threading
import time
from collections import deque
from collections.abc import Callable, Coroutine
from typing import Any, NamedTuple

from actors import ActorSystem
from supervisor import lifecycle
from supervisor.aio import Cancelled, Future, Task, wait_for
from supervisor.command import CommandProcess
from supervisor.errors import StartError, SupervisorError
from supervisor.exits import Exit, Reason
from supervisor.health import watch_heartbeat
from supervisor.intensity import RestartIntensity
from supervisor.procs import ActorProcess, Incarnation
from supervisor.rootio import in_root, on_root
from supervisor.spec import ChildSpec, Restart, Strategy, SupervisorSpec
from supervisor.states import ChildStatus, SupervisorState
from supervisor.tree import Tree

__all__ = ["ChildInfo", "Supervisor", "SupervisorProcess", "start_supervisor"]

log = logging.getLogger("supervisor")

Job = Callable[[], Coroutine[Any, Any, Any]]


class ChildInfo(NamedTuple):
    """One row of :meth:`Supervisor.which_children` (OTP: ``{Id, Child, Type, Modules}``).

    ``pid`` is the process id while running, ``"restarting"`` while a restart
    is pending, None when not running. A running nested supervisor lives in
    the root, so its pid is the root's.
    """

    id: str
    pid: int | str | None
    type: str
    module: str


class Child:
    """A supervisor's record of one child spec."""

    __slots__ = ("spec", "inc", "status", "restarts", "backoff_n", "timer", "last_exit", "down_since")

    def __init__(self, spec: ChildSpec) -> None:
        self.spec = spec
        self.inc: Incarnation | None = None
        self.status = ChildStatus.STOPPED
        self.restarts = 0
        self.backoff_n = 0
        self.timer: int | None = None
        self.last_exit: Exit | None = None
        self.down_since: float | None = None

    @property
    def id(self) -> str:
        return self.spec.id


class Supervisor:
    """A supervisor; build it with :func:`start_supervisor` (or as a child spec)."""

    def __init__(self, tree: Tree, spec: SupervisorSpec, name: str, parent: Supervisor | None = None) -> None:
        self.tree = tree
        self.system: ActorSystem = tree.system
        self.loop = tree.loop
        self.spec = spec
        self.name = name
        self.parent = parent
        self.path: str = f"{parent.path}/{name}" if parent is not None else name
        self.simple = spec.strategy == "simple_one_for_one"
        self.template = spec.children[0] if self.simple else None
        self.children: list[Child] = [] if self.simple else [Child(c) for c in spec.children]
        self.intensity = RestartIntensity(spec.intensity, spec.period)
        self.state = SupervisorState.NEW
        self.exited: Future[Exit] = Future(self.loop)
        self.started_at = time.monotonic()
        self._jobs: deque[tuple[Job, Future[Any], bool]] = deque()
        self._task: Task | None = None
        self._stopper: Task | None = None  # the shutdown in progress, if any
        self._seq = itertools.count(1)

    def __repr__(self) -> str:
        return f"<Supervisor {self.path} {self.spec.strategy} {self.state}>"

    # == public API (any thread but the root IO thread) =====================
    def which_children(self) -> list[ChildInfo]:
        """The children in start order: id, pid | "restarting" | None, type, module."""
        return on_root(self.system, self._which_children)

    def count_children(self) -> dict[str, int]:
        """``specs``, ``active`` (running), ``supervisors`` and ``workers``."""
        return on_root(self.system, self._count_children)

    def start_child(self, *args: Any, name: str | None = None) -> str:
        """Add and start a child; returns its id.

        Takes a :class:`ChildSpec`, or for ``simple_one_for_one`` the extra
        start arguments (appended to the template's; ``name`` is optional).
        """
        if self.simple:
            return self._call(lambda: self._start_dynamic(args, name))
        if len(args) != 1 or not isinstance(args[0], ChildSpec):
            raise TypeError("start_child takes one ChildSpec (extra arguments are for simple_one_for_one)")
        return self._call(lambda: self._start_new(args[0]))

    def terminate_child(self, child_id: str) -> None:
        """Stop a child per its shutdown mode; it is not restarted (a temporary one is dropped)."""
        self._call(lambda: self._terminate_child(child_id))

    def restart_child(self, child_id: str) -> int | None:
        """Start a stopped child again (not counted as a restart); returns its pid."""
        return self._call(lambda: self._restart_child(child_id))

    def delete_child(self, child_id: str) -> None:
        """Forget a stopped child's spec (and its journal and snapshot)."""
        self._call(lambda: self._delete_child(child_id))

    def bounce(self, child_id: str, *, deadline: float | None = None) -> int | None:
        """Stop a child and start it again now (an operator's restart); returns the new pid.

        Counted in the child's restarts column, not in the restart intensity.
        ``deadline`` (``time.monotonic()``): if the job is still queued behind
        others then, it is not carried out (``SupervisorError("expired")``).
        """
        async def job() -> int | None:
            late = 0.0 if deadline is None else time.monotonic() - deadline
            if late > 0:
                raise SupervisorError("expired", f"restart of {child_id!r} not carried out: its deadline passed "
                                      f"{late:.2f} s before {self.path} got to it (other jobs ran first)")
            return await self._bounce(child_id)

        return self._call(job)

    def child(self, child_id: str) -> Supervisor:
        """The current incarnation of nested supervisor ``child_id``."""

        def find() -> Supervisor:
            c = self._find(child_id)
            if c is None or not isinstance(c.inc, SupervisorProcess) or c.inc.sup is None:
                raise SupervisorError("not_found", f"{self.path} has no running supervisor child {child_id!r}")
            return c.inc.sup

        return on_root(self.system, find)

    def stop(self, timeout: float | None = None) -> Exit | None:
        """Stop all children in reverse order; returns the supervisor's exit (None on timeout)."""
        on_root(self.system, self._shutdown)
        return self.wait(timeout)

    def wait(self, timeout: float | None = None) -> Exit | None:
        """Block until this supervisor has exited (stopped, or gave up); None on timeout."""
        if in_root(self.system):
            raise RuntimeError("Supervisor.wait() would block the root IO thread; call it from another thread")
        done = threading.Event()
        on_root(self.system, lambda: self.exited.add_done_callback(lambda _: done.set()))
        if not done.wait(timeout):
            return None
        return self.exited.result()

    @property
    def running(self) -> bool:
        return self.state in (SupervisorState.STARTING, SupervisorState.RUNNING)

    def _call(self, job: Job, timeout: float | None = None) -> Any:
        if in_root(self.system):
            raise RuntimeError(
                "supervisor calls block until done and cannot run on the root IO thread "
                "(an exit listener, an event listener); call them from another thread"
            )
        done = threading.Event()
        box: list[Future[Any]] = []

        def post() -> None:
            fut = self._post(job)
            fut.add_done_callback(lambda f: _settle(box, done, f))

        self.loop.call_soon_threadsafe(post)
        if not done.wait(timeout):
            raise TimeoutError(f"supervisor {self.path} did not answer within {timeout} s")
        err = box[0].exception()
        if isinstance(err, Cancelled):
            raise SupervisorError("shutdown", f"supervisor {self.path} is shutting down")
        return box[0].result()

    # == jobs: one at a time, in order (root IO thread) =====================
    def _post(self, job: Job, internal: bool = False) -> Future[Any]:
        fut: Future[Any] = Future(self.loop)
        if self.state in (SupervisorState.STOPPING, SupervisorState.STOPPED):
            fut.set_exception(SupervisorError("shutdown", f"supervisor {self.path} is shutting down"))
            return fut
        self._jobs.append((job, fut, internal))
        self._pump()
        return fut

    def _pump(self) -> None:
        if self._task is not None or not self._jobs or self.state in (SupervisorState.STOPPING, SupervisorState.STOPPED):
            return
        job, fut, internal = self._jobs.popleft()
        task = self._task = Task(self.loop, job())

        def done(f: Future[Any]) -> None:
            if self._task is task:
                self._task = None
            err = f.exception()
            if err is None:
                fut.set_result(f.result())
            else:
                if internal and not isinstance(err, (Cancelled, SupervisorError)):
                    log.error("supervisor %s: internal error", self.path, exc_info=err)
                fut.set_exception(err)
            self._pump()

        task.future.add_done_callback(done)

    # == starting ============================================================
    def _begin(self) -> Future[bool]:
        """Claim the children's names and start them in order (the init job)."""
        self.state = SupervisorState.STARTING
        claimed = []
        try:
            for c in self.children:
                self.tree.claim(c.id, self.path, c.spec.kind)
                claimed.append(c.id)
        except SupervisorError as exc:
            for cid in claimed:
                self.tree.release(cid)
            self.state = SupervisorState.STOPPED
            self.exited.set_result(Exit(Reason.ERROR, None, str(exc)))
            fut: Future[bool] = Future(self.loop)
            fut.set_exception(StartError(f"supervisor {self.path} cannot start: {exc}", str(exc)))
            return fut
        return self._post(self._init)

    async def _init(self) -> bool:
        for c in list(self.children):
            if not await self._start(c, restart=False):
                detail = f"failed to start child {c.id!r}: {c.last_exit}"
                await self._terminate_all()
                self._finish(Exit(Reason.ERROR, None, detail))
                return False
        self.state = SupervisorState.RUNNING
        return True

    def _incarnation(self, c: Child) -> Incarnation:
        kind = c.spec.kind
        if kind == "actor":
            return ActorProcess(self.tree, c.spec, self.path, self.tree.journal(c.id))
        if kind == "command":
            return CommandProcess(self.tree, c.spec, self.path)
        return SupervisorProcess(self.tree, c.spec, self.path, self)

    async def _start(self, c: Child, restart: bool) -> bool:
        """Start one incarnation of ``c`` and wait until it is ready; False if it failed."""
        inc = self._incarnation(c)
        c.inc, c.status = inc, ChildStatus.STARTING
        inc.exited.add_done_callback(lambda _: self._on_exit(c, inc))
        inc.start()
        timeout = None if c.spec.type == "supervisor" else c.spec.start_timeout
        in_time = await wait_for(self.loop, inc.ready, timeout)
        if in_time and inc.ready.result():
            c.status = ChildStatus.RUNNING
            ev = self._event_fields(c, inc)
            if restart:
                c.restarts += 1
                down = None if c.down_since is None else round(time.monotonic() - c.down_since, 4)
                took_over = isinstance(inc, ActorProcess) and inc.from_standby
                self.tree.events.emit("restarted", **ev, restarts=c.restarts, downtime=down, standby=took_over)
            else:
                self.tree.events.emit("started", **ev, type=c.spec.type)
            c.down_since = None
            self._watch(c, inc)
            return True
        if not in_time:
            inc.kill(Exit(Reason.ERROR, None, f"not ready within {timeout} s"))
        ex = await inc.exited
        if c.inc is inc:
            c.inc, c.status = None, ChildStatus.STOPPED
        c.last_exit = ex
        c.down_since = c.down_since or time.monotonic()
        self.tree.events.emit(
            "crashed", **self._event_fields(c, inc), phase="start", reason=ex.reason, detail=ex.detail, exit_code=ex.code
        )
        return False

    def _watch(self, c: Child, inc: Incarnation) -> None:
        if isinstance(inc, ActorProcess) and c.spec.heartbeat:
            watch_heartbeat(self.tree, inc, inc.journal, c.spec.heartbeat)
        if isinstance(inc, ActorProcess) and c.spec.standby:
            self.tree.keep_standby(c.spec, self.path)  # the next one gets ready while this one serves
        if isinstance(inc, (ActorProcess, CommandProcess)):
            self.tree.monitor.watch(inc)

    def _event_fields(self, c: Child, inc: Incarnation | None) -> dict[str, Any]:
        return {"supervisor": self.path, "child": c.id, "pid": None if inc is None else inc.pid}

    # == exits and restarts ==================================================
    def _on_exit(self, c: Child, inc: Incarnation) -> None:
        if inc.stopping or c.inc is not inc or self.state in (SupervisorState.STOPPING, SupervisorState.STOPPED):
            return  # a stop we asked for, or a start that fails (its job handles it)
        self._post(lambda: self._handle_exit(c, inc), internal=True)

    async def _handle_exit(self, c: Child, inc: Incarnation) -> None:
        if c.inc is not inc or self.state != SupervisorState.RUNNING:
            return  # a restart of siblings has already replaced it
        ex = inc.exited.result()
        c.inc, c.status, c.last_exit = None, ChildStatus.STOPPED, ex
        c.down_since = time.monotonic()
        up = c.down_since - (inc.ready_at or inc.started_at)
        if c.spec.backoff is not None and up >= c.spec.backoff.reset_window:
            c.backoff_n = 0
        self.tree.events.emit(
            "exited" if ex.normal else "crashed",
            **self._event_fields(c, inc), phase="run", reason=ex.reason, detail=ex.detail, exit_code=ex.code,
        )
        kind = Restart(c.spec.restart)
        if not kind.restarts(ex.normal):
            self.tree.drop_standby(c.id)
            if kind is Restart.TEMPORARY or self.simple:
                self._remove(c)
            return
        await self._restart_counted(c)

    async def _restart_counted(self, c: Child) -> None:
        """Restart ``c`` (and its group) if the restart intensity allows it; else give up."""
        if self.intensity.add():
            await self._restart(c)
        else:
            await self._give_up(c)

    async def _restart(self, c: Child) -> None:
        group = Strategy(self.spec.strategy).involves(self.children, c)
        for o in reversed(group):
            if o is c:
                continue
            if o.inc is not None:
                await self._terminate(o)
            self._cancel_timer(o)
            if o.spec.restart == "temporary":
                self._remove(o)  # OTP: a temporary child killed by a sibling's restart is dropped
        group = [o for o in group if o in self.children]
        for o in group:
            o.status = ChildStatus.RESTARTING
            o.down_since = o.down_since or time.monotonic()
        delay = 0.0
        if c.spec.backoff is not None:
            delay = c.spec.backoff.delay(c.backoff_n)
            c.backoff_n += 1
        if delay <= 0:
            await self._start_group(group)
            return
        self.tree.events.emit("restarting", **self._event_fields(c, None), delay=round(delay, 4))

        def fire() -> None:
            c.timer = None
            if self.state == SupervisorState.RUNNING:
                self._post(lambda: self._start_group(group), internal=True)

        c.timer = self.loop.call_later(delay, fire)

    async def _start_group(self, group: list[Child]) -> None:
        for i, o in enumerate(group):
            if o not in self.children or o.status != ChildStatus.RESTARTING:
                continue  # terminated or deleted meanwhile
            if not await self._start(o, restart=True):
                o.status = ChildStatus.RESTARTING
                for rest in group[i + 1:]:
                    if rest.status == ChildStatus.RESTARTING:
                        rest.status = ChildStatus.STOPPED  # OTP: undefined until the retry starts them
                # Retry after whatever else is queued, through the intensity accounting.
                self._post(functools.partial(self._try_again, o), internal=True)
                return

    async def _try_again(self, c: Child) -> None:
        if self.state != SupervisorState.RUNNING or c not in self.children or c.status != ChildStatus.RESTARTING:
            return
        await self._restart_counted(c)

    async def _give_up(self, c: Child) -> None:
        self.tree.events.emit(
            "gave_up", supervisor=self.path, child=c.id, restarts=len(self.intensity),
            intensity=self.spec.intensity, period=self.spec.period,
        )
        if c in self.children and (c.spec.restart == "temporary" or self.simple):
            self._remove(c)
        self.state = SupervisorState.STOPPING
        await self._terminate_all()
        if self.parent is not None:
            self.tree.events.emit("escalated", supervisor=self.path, parent=self.parent.path)
        self._finish(Exit(Reason.SHUTDOWN, None, "reached max restart intensity"))

    # == stopping ============================================================
    async def _terminate(self, c: Child) -> Exit | None:
        """Stop ``c``'s incarnation per its shutdown mode and wait for its exit."""
        self._cancel_timer(c)
        inc = c.inc
        if inc is None:
            if c.status == ChildStatus.RESTARTING:
                c.status = ChildStatus.STOPPED
            return None
        inc.stopping = True
        mode = c.spec.shutdown
        if not inc.exited.done():
            if mode == "brutal_kill":
                inc.kill()
            else:
                inc.stop()
                if isinstance(mode, float) and not await wait_for(self.loop, inc.exited, mode):
                    log.warning("%s/%s did not stop within %s s: killing it", self.path, c.id, mode)
                    inc.kill()
        ex = await inc.exited
        if c.inc is inc:
            c.inc, c.status = None, ChildStatus.STOPPED
        self.tree.events.emit("stopped", **self._event_fields(c, inc), reason=ex.reason, detail=ex.detail)
        expected = ex.reason == Reason.SHUTDOWN or (ex.reason == Reason.KILLED and mode == "brutal_kill")
        if not expected and not (ex.normal and c.spec.restart != "permanent"):
            log.warning("%s/%s: shutdown error: it ended with %s", self.path, c.id, ex)
        return ex

    async def _terminate_all(self) -> None:
        for c in self.children:
            self._cancel_timer(c)
        if self.simple:  # OTP: dynamic children are stopped all at once
            tasks = [Task(self.loop, self._terminate(c)) for c in self.children if c.inc is not None]
            for t in tasks:
                await t.future
        else:
            for c in reversed(list(self.children)):
                if c.inc is not None:
                    await self._terminate(c)
        for c in self.children:
            c.status = ChildStatus.STOPPED
            self.tree.drop_standby(c.id)

    def _shutdown(self) -> Future[Exit]:
        """Stop everything in reverse order, whatever the supervisor was doing (IO thread)."""
        if self.state in (SupervisorState.STOPPING, SupervisorState.STOPPED):
            return self.exited
        self.state = SupervisorState.STOPPING
        self._drop_jobs()
        self._stopper = Task(self.loop, self._shutdown_job())
        return self.exited

    async def _shutdown_job(self) -> None:
        await self._terminate_all()
        self._finish(Exit(Reason.SHUTDOWN, None, "requested"))

    def _kill(self) -> None:
        """Kill every process below this supervisor at once (its parent's brutal kill)."""
        if self.state == SupervisorState.STOPPED:
            return
        self.state = SupervisorState.STOPPING
        self._drop_jobs()
        if self._stopper is not None:  # a clean shutdown that took too long: overtaken
            self._stopper.cancel()
            self._stopper = None
        incs = [c.inc for c in self.children if c.inc is not None]
        for c in self.children:
            self._cancel_timer(c)
            self.tree.drop_standby(c.id)
        for inc in incs:
            inc.stopping = True
            inc.kill()

        async def reap() -> None:
            for inc in incs:
                await inc.exited
            for c in self.children:
                c.inc, c.status = None, ChildStatus.STOPPED
            self._finish(Exit(Reason.KILLED, None, "killed by its supervisor"))

        Task(self.loop, reap())

    def _drop_jobs(self, cancel_running: bool = True) -> None:
        jobs, self._jobs = self._jobs, deque()
        for _, fut, _ in jobs:
            fut.set_exception(SupervisorError("shutdown", f"supervisor {self.path} is shutting down"))
        if cancel_running and self._task is not None:
            task, self._task = self._task, None
            task.cancel()

    def _finish(self, ex: Exit) -> None:
        self.state = SupervisorState.STOPPED
        self._drop_jobs(cancel_running=False)  # the running job may be the one finishing us
        for c in self.children:
            self._cancel_timer(c)
            if self.simple:
                self.tree.forget(c.id)  # dynamic children do not outlive their supervisor
            else:
                self.tree.release(c.id)
        if self.parent is None and self in self.tree.roots:
            self.tree.roots.remove(self)
        self.exited.set_result(ex)

    def _cancel_timer(self, c: Child) -> None:
        if c.timer is not None:
            self.loop.cancel(c.timer)
            c.timer = None

    def _remove(self, c: Child) -> None:
        if c in self.children:
            self.children.remove(c)
        self.tree.drop_standby(c.id)
        self.tree.forget(c.id)

    def _find(self, child_id: str) -> Child | None:
        for c in self.children:
            if c.id == child_id:
                return c
        return None

    # == calls (jobs) ========================================================
    async def _start_new(self, spec: ChildSpec) -> str:
        old = self._find(spec.id)
        if old is not None:
            if old.inc is not None:
                raise SupervisorError("already_started", f"child {spec.id!r} is already running (pid {old.inc.pid})")
            raise SupervisorError("already_present", f"child {spec.id!r} exists (stopped): restart_child or delete_child it")
        self.tree.claim(spec.id, self.path, spec.kind)
        c = Child(spec)
        self.children.append(c)
        if not await self._start(c, restart=False):
            self._remove(c)
            raise StartError(f"child {spec.id!r} failed to start: {c.last_exit}", str(c.last_exit))
        return spec.id

    async def _start_dynamic(self, args: tuple[Any, ...], name: str | None) -> str:
        assert self.template is not None
        if name is None:
            name = f"{self.template.id}.{next(self._seq)}"
            while name in self.tree.names:
                name = f"{self.template.id}.{next(self._seq)}"
        spec = self.template.with_args(name, args)
        self.tree.claim(name, self.path, spec.kind)
        c = Child(spec)
        self.children.append(c)
        if not await self._start(c, restart=False):
            self._remove(c)
            raise StartError(f"child {name!r} failed to start: {c.last_exit}", str(c.last_exit))
        return name

    def _need(self, child_id: str) -> Child:
        c = self._find(child_id)
        if c is None:
            raise SupervisorError("not_found", f"{self.path} has no child {child_id!r}")
        return c

    def _need_stopped(self, child_id: str) -> Child:
        """The child ``child_id``, which must be stopped (not running, not restarting)."""
        c = self._need(child_id)
        if c.status == ChildStatus.RESTARTING:
            raise SupervisorError("restarting", f"child {child_id!r} is restarting")
        if c.inc is not None:
            raise SupervisorError("running", f"child {child_id!r} is running; terminate_child it first")
        return c

    async def _terminate_child(self, child_id: str) -> None:
        c = self._need(child_id)
        self.tree.drop_standby(child_id)
        await self._terminate(c)
        c.status = ChildStatus.STOPPED
        if c.spec.restart == "temporary" or self.simple:
            self._remove(c)

    async def _restart_child(self, child_id: str) -> int | None:
        if self.simple:
            raise SupervisorError("simple_one_for_one", "restart_child is not for simple_one_for_one children")
        c = self._need_stopped(child_id)
        if not await self._start(c, restart=False):
            raise StartError(f"child {child_id!r} failed to start: {c.last_exit}", str(c.last_exit))
        return c.inc.pid if c.inc is not None else None

    async def _delete_child(self, child_id: str) -> None:
        if self.simple:
            raise SupervisorError("simple_one_for_one", "delete_child is not for simple_one_for_one children")
        self._remove(self._need_stopped(child_id))

    async def _bounce(self, child_id: str) -> int | None:
        c = self._need(child_id)
        if c.inc is not None:
            await self._terminate(c)
        c.status = ChildStatus.RESTARTING
        c.down_since = time.monotonic()
        if not await self._start(c, restart=True):
            c.status = ChildStatus.RESTARTING
            self._post(lambda: self._try_again(c), internal=True)
            raise StartError(f"child {child_id!r} failed to start: {c.last_exit}", str(c.last_exit))
        return c.inc.pid if c.inc is not None else None

    # == introspection (root IO thread) ======================================
    def _which_children(self) -> list[ChildInfo]:
        out = []
        for c in self.children:
            pid: int | str | None
            if c.status == ChildStatus.RESTARTING:
                pid = "restarting"
            elif c.inc is not None and c.status == ChildStatus.RUNNING:
                pid = c.inc.pid
            else:
                pid = None
            out.append(ChildInfo(c.id, pid, c.spec.type or "worker", c.spec.module))
        return out

    def _count_children(self) -> dict[str, int]:
        sups = sum(1 for c in self.children if c.spec.type == "supervisor")
        active = sum(1 for c in self.children if c.inc is not None and c.status == ChildStatus.RUNNING)
        return {"specs": len(self.children), "active": active, "supervisors": sups, "workers": len(self.children) - sups}

    def _locate(self, name: str) -> tuple[Supervisor, Child] | None:
        """Find child ``name`` anywhere below this supervisor."""
        for c in self.children:
            if c.id == name:
                return self, c
            if isinstance(c.inc, SupervisorProcess) and c.inc.sup is not None:
                found = c.inc.sup._locate(name)
                if found is not None:
                    return found
        return None

    def _rows(self) -> list[dict[str, Any]]:
        """Status rows of this subtree (root IO thread)."""
        now = time.monotonic()
        rows: list[dict[str, Any]] = []
        for c in self.children:
            inc = c.inc
            running = inc is not None and c.status == ChildStatus.RUNNING
            row: dict[str, Any] = {
                "name": c.id,
                "supervisor": self.path,
                "kind": c.spec.kind,
                "restart": c.spec.restart,
                "status": c.status,
                "pid": inc.pid if running and inc is not None else None,
                "restarts": c.restarts,
                "uptime": round(now - (inc.ready_at or inc.started_at), 1) if running and inc is not None else 0.0,
                "cpu_percent": round(inc.usage.cpu_percent, 1) if running and inc is not None else None,
                "rss_mb": round(inc.usage.rss_mb, 1) if running and inc is not None and inc.usage.at else None,
                "lifecycle": None,
                "last_exit": str(c.last_exit) if c.last_exit is not None else None,
                "standby": self.tree.standbys[c.id].state if c.id in self.tree.standbys else None,
            }
            if c.spec.managed and c.id in self.tree.journals:
                row["lifecycle"] = lifecycle.state_name(self.tree.journals[c.id].state())
            rows.append(row)
            if isinstance(inc, SupervisorProcess) and inc.sup is not None:
                rows.extend(inc.sup._rows())
        return rows


class SupervisorProcess(Incarnation):
    """One incarnation of a nested supervisor (it lives on the root IO thread)."""

    kind = "supervisor"

    def __init__(self, tree: Tree, spec: ChildSpec, path: str, parent: Supervisor) -> None:
        super().__init__(tree, spec, path)
        self.parent = parent
        self.sup: Supervisor | None = None

    @property
    def pid(self) -> int | None:
        return os.getpid() if self.sup is not None and self.sup.running else None

    def start(self) -> None:
        sup = self.sup = Supervisor(self.tree, self.spec.start, self.name, self.parent)
        sup.exited.add_done_callback(lambda f: self._ended(f.result()))
        ready = sup._begin()
        ready.add_done_callback(lambda f: self._set_ready() if f.exception() is None and f.result() else None)

    def _ended(self, ex: Exit) -> None:
        if self.stopping and ex.reason == Reason.SHUTDOWN:
            ex = Exit(Reason.SHUTDOWN, None, ex.detail)
        self.ready.set_result(False)
        self.exited.set_result(ex)

    def stop(self) -> None:
        self.stopping = True
        if self.sup is not None:
            self.sup._shutdown()

    def kill(self, cause: Exit | None = None) -> None:
        if cause is not None and self.cause is None:
            self.cause = cause
        if self.sup is not None:
            self.sup._kill()


def start_supervisor(
    system: ActorSystem, spec: SupervisorSpec, name: str = "root", *, timeout: float | None = None
) -> Supervisor:
    """Start a root supervisor and its children (in order); returns once all are ready.

    Raises :class:`~supervisor.errors.StartError` if a child fails to start
    (the ones already started are stopped again, in reverse order).
    """
    if in_root(system):
        raise RuntimeError("start_supervisor() blocks; call it from another thread than the root IO thread")
    tree = Tree.of(system)
    done = threading.Event()
    box: list[Any] = []

    def go() -> None:
        sup = Supervisor(tree, spec, name)
        tree.roots.append(sup)
        box.append(sup)
        sup._begin().add_done_callback(lambda f: _settle(box, done, f))

    on_root(system, go)
    if not done.wait(timeout):
        raise TimeoutError(f"supervisor {name!r} did not start within {timeout} s")
    sup, fut = box
    if fut.exception() is not None:
        raise fut.exception()
    if not fut.result():
        ex = on_root(system, lambda: sup.exited.result() if sup.exited.done() else None)
        raise StartError(f"supervisor {name!r} failed to start: {ex}", str(ex))
    return sup


def _settle(box: list[Any], done: threading.Event, fut: Any) -> None:
    """Hand a finished future to a thread waiting on ``done``."""
    box.append(fut)
    done.set()
