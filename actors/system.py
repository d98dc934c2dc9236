"""``ActorSystem``: the root of a run: run directory, fork server, spawning.

Example::

    >>> from actors import Actor, ActorSystem
    >>> class Echo(Actor):
    ...     def on_receive(self, message):
    ...         return message
    >>> with ActorSystem() as system:                   # doctest: +SKIP
    ...     echo = system.spawn(Echo, "echo")
    ...     echo.ask("hi", timeout=2).get()
    'hi'
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import os
import secrets
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import msgpack
import pykka
import zmq

from actors import wire
from actors.actor import Actor
from actors.app import env
from actors.child import TAKE_OVER, child_main
from actors.errors import ActorError
from actors.forkserver import ForkServer, cleanup_pid
from actors.host import ActorHost
from actors.loop import Loop
from actors.private import check_folder, private_dir
from actors.ref import ActorRef
from actors.runtime import Runtime, current, set_current, shm_prefix
from actors.shm import sweep

__all__ = ["ActorSystem", "ProcessInfo"]

log = logging.getLogger("actors.system")

#: Blocked in a standby from its birth until it takes over or stops (see actors.spawn).
_STANDBY_SIGNALS = {TAKE_OVER, signal.SIGTERM}


class ProcessInfo:
    """What the root knows about one actor process."""

    def __init__(self, name: str, spec: dict[str, Any]) -> None:
        self.name = name
        self.spec = spec
        self.pid: int | None = None
        self.started_at = 0.0
        self.ready = threading.Event()
        self.exited = threading.Event()
        self.exit_code: int | None = None
        self.failure: str | None = None
        #: "fork" (a child of the fork server) or "spawn" (a fresh interpreter: actors.spawn).
        self.method = "fork"
        #: A warm standby that has not taken over yet (see :meth:`ActorSystem.take_over`).
        self.standby = False
        #: Set once a standby said it is ready to take over.
        self.standing_by = threading.Event()


def class_path(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"


def _run_base() -> str:
    # ipc paths are limited to ~107 bytes: $<APP>_RUN_BASE can shorten a long $XDG_RUNTIME_DIR.
    override = env("RUN_BASE")
    return check_folder(override) if override else private_dir()


class ActorSystem:
    """Owns a run: its directory (0700, in :func:`actors.private.private_dir`), fork server, processes and registry.

    One per process at a time. ``spawn`` starts actors; ``shutdown`` stops
    them in reverse order and removes everything the run left behind.
    """

    def __init__(self, *, log_level: int = logging.INFO) -> None:
        with contextlib.suppress(RuntimeError):
            if not current().closed:
                raise ActorError("an ActorSystem is already running in this process; shut it down first")
        self.run_id = secrets.token_hex(4)
        self.run_dir = os.path.join(_run_base(), f"run-{self.run_id}")
        os.mkdir(self.run_dir, 0o700)  # fails if it exists: never adopt a folder someone else made
        self.log_level = log_level
        # Fork the server first: before this process opens sockets of its own.
        self.forkserver = ForkServer(self.run_dir, shm_prefix(self.run_id), child_main)
        self.rt = Runtime(self.run_dir, self.run_id)
        set_current(self.rt)
        self.loop: Loop = self.rt.client_loop()
        self.procs: dict[str, ProcessInfo] = {}
        self.order: list[str] = []
        self.attached: dict[str, tuple[pykka.ActorRef, threading.Thread]] = {}
        self._attached_hosts: dict[str, ActorHost] = {}
        self._tokens = itertools.count(1)
        self._spawning: dict[int, ProcessInfo] = {}
        self._spawned: dict[int, tuple[subprocess.Popen[bytes], ProcessInfo, int]] = {}  # pid -> (proc, info, pidfd)
        self.exit_listeners: list[Callable[[ProcessInfo], None]] = []
        #: Run first by :meth:`shutdown` (a supervision tree stops itself here).
        self.before_shutdown: list[Callable[[], None]] = []
        self.event_listeners: list[Callable[[list[Any]], None]] = []
        self.closed = False
        #: Why no process can be started any more (the fork server died), else None.
        self.forkserver_failure: str | None = None
        self.rt.on_client(self._setup_loop)

    # -- root IO (runs on the client loop thread) ---------------------------
    def _setup_loop(self) -> None:
        ctl = self.rt.ctx.socket(zmq.ROUTER)
        ctl.setsockopt(zmq.LINGER, 0)
        ctl.bind(f"ipc://{self.run_dir}/_root.ctl")
        self._ctl = ctl
        self.loop.add(ctl, self._on_ctl)
        self.loop.add(self.forkserver.fileno(), self._on_forkserver)

    def _on_ctl(self) -> None:
        while True:
            try:
                _, frame = self._ctl.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            except ValueError:
                continue
            try:
                msg = msgpack.unpackb(frame)
                kind, name, pid = msg[0], msg[1], msg[2]
            except Exception:
                log.warning("dropped a corrupt control frame")
                continue
            spawned = self._spawned.get(pid) if isinstance(pid, int) else None
            if spawned is not None and spawned[1].standby:  # a standby's notes are its own
                if kind == "standby":
                    spawned[1].standing_by.set()
                elif kind == "failed":
                    spawned[1].failure = msg[3]
                for fn in self.event_listeners:
                    fn(msg)
                continue
            info = self.procs.get(name)
            if info is not None and info.pid is None:
                info.pid = pid  # the ready note overtook the fork server's "spawned"
            if info is not None and info.pid == pid:
                if kind == "ready":
                    info.ready.set()
                elif kind == "failed":
                    info.failure = msg[3]
            for fn in self.event_listeners:
                fn(msg)

    def _on_forkserver(self) -> None:
        for msg in self.forkserver.recv_all():
            if msg[0] == "spawned":
                info = self._spawning.pop(msg[1], None)
                if info is not None:
                    info.pid = msg[2]
            elif msg[0] == "exit":
                _, pid, code, name = msg
                info = self.procs.get(name)
                if info is None or info.pid != pid:
                    continue
                self._exited(info, code)
        if self.forkserver.lost and self.forkserver_failure is None:
            self._forkserver_lost()

    def _exited(self, info: ProcessInfo, code: int | None, failure: str | None = None) -> None:
        if failure is not None and info.failure is None:
            info.failure = failure
        info.exit_code = code
        info.exited.set()
        for fn in self.exit_listeners:
            fn(info)

    def _forkserver_lost(self) -> None:
        """The fork server died: its children died with it (PDEATHSIG); say so instead of waiting forever."""
        self.loop.remove(self.forkserver.fileno())  # its closed end would stay readable: no spinning
        self.forkserver_failure = (
            f"the run's fork server (pid {self.forkserver.pid}) died ({self.forkserver.exit_status()}), "
            "and every actor process with it: this run can start no process; stop it and start it again"
        )
        log.error("%s", self.forkserver_failure)
        self._spawning.clear()
        for info in list(self.procs.values()):
            if not info.exited.is_set():
                self._exited(info, -signal.SIGKILL, self.forkserver_failure)

    # -- processes ----------------------------------------------------------
    def start_process(self, spec: dict[str, Any], *, method: str = "fork", standby: bool = False) -> ProcessInfo:
        """Start (or restart) the actor process described by ``spec``; returns at once.

        ``method``: "fork" (from the fork server: milliseconds) or "spawn" (a
        fresh interpreter, :mod:`actors.spawn`: for actors that may use CUDA,
        which does not survive ``fork``). ``standby=True`` (spawned) starts a
        warm standby: it gets ready and waits for :meth:`take_over`; until
        then it is not the actor ``spec["name"]`` (exit listeners still see
        its exit, with this ``ProcessInfo``). The supervisor uses this; most
        code wants :meth:`spawn`.
        """
        if method not in ("fork", "spawn"):
            raise ValueError(f"start method must be 'fork' or 'spawn', not {method!r}")
        if standby:
            method = "spawn"
        name = spec["name"]
        info = ProcessInfo(name, spec)
        info.method, info.standby = method, standby
        token = next(self._tokens)

        def go() -> None:
            if not standby:
                self.procs[name] = info
            info.started_at = time.monotonic()
            if self.forkserver_failure is not None:  # a start that fails at once, with the reason
                self._exited(info, None, self.forkserver_failure)
                return
            if method == "spawn":
                self._spawn_process(info, dict(spec, standby=standby))
                return
            self._spawning[token] = info
            self.forkserver.send(["spawn", token, spec])

        self.rt.on_client(go)
        return info

    def _spawn_process(self, info: ProcessInfo, spec: dict[str, Any]) -> None:
        """Run ``python -m actors.spawn`` with ``spec`` on its stdin (root IO thread)."""
        spec["root_pid"] = os.getpid()
        env = dict(os.environ)
        # The child imports the actor's class itself: give it the root's import path.
        env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)
        # A standby is born with the take-over signal blocked (the mask survives exec): one sent
        # while its interpreter still starts waits for it instead of killing it.
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, _STANDBY_SIGNALS) if spec["standby"] else None
        try:
            proc = subprocess.Popen([sys.executable, "-m", "actors.spawn"], stdin=subprocess.PIPE, env=env)
        except OSError as exc:
            self._exited(info, None, f"cannot spawn {sys.executable} -m actors.spawn: {exc}")
            return
        finally:
            if mask is not None:
                signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        assert proc.stdin is not None
        with contextlib.suppress(BrokenPipeError):  # it died at once: its exit says so below
            proc.stdin.write(msgpack.packb(spec))
        with contextlib.suppress(BrokenPipeError):
            proc.stdin.close()
        info.pid = proc.pid
        pidfd = os.pidfd_open(proc.pid)  # readable once it exits: no polling
        self._spawned[proc.pid] = (proc, info, pidfd)
        self.loop.add(pidfd, lambda: self._on_spawned_exit(proc.pid))

    def _on_spawned_exit(self, pid: int) -> None:
        proc, info, pidfd = self._spawned.pop(pid)
        self.loop.remove(pidfd)
        os.close(pidfd)
        code = proc.wait()
        cleanup_pid(self.run_dir, shm_prefix(self.run_id), pid)  # what the fork server does for its own
        self._exited(info, code)

    def take_over(self, info: ProcessInfo) -> None:
        """Make the waiting standby ``info`` the actor ``info.name`` now (root IO thread).

        It binds the actor's mailbox, so senders re-send to it what its
        predecessor had not acknowledged, and reports ready as any start does.
        """
        if not info.standby or info.pid is None or info.exited.is_set():
            raise ActorError(f"{info.name!r}: that process is not a waiting standby")
        info.standby = False
        self.procs[info.name] = info
        with contextlib.suppress(ProcessLookupError):
            os.kill(info.pid, TAKE_OVER)

    def make_spec(self, cls: type[Actor], name: str, args: tuple[Any, ...], kwargs: dict[str, Any], **opts: Any) -> dict[str, Any]:
        """The process spec ``start_process`` takes: msgpack-able data the fork server hands the child.

        ``opts``: ``heartbeat``, ``poison_limit``, ``nice``, ``cpu_affinity`` and
        ``extensions`` (a list of :func:`actors.extension.extension_spec` pairs).
        """
        return {
            "name": name,
            "cls": class_path(cls),
            "args": list(args),
            "kwargs": kwargs,
            "run_dir": self.run_dir,
            "run_id": self.run_id,
            "log_level": self.log_level,
            "heartbeat": opts.get("heartbeat", 1.0),
            "poison_limit": opts.get("poison_limit", 3),
            "nice": opts.get("nice"),
            "cpu_affinity": opts.get("cpu_affinity"),
            # [["module:Class", config], ...] (actors.extension.extension_spec): data, never pickle
            "extensions": [list(e) for e in opts.get("extensions", ())],
        }

    def spawn(
        self,
        cls: type[Actor],
        name: str,
        *args: Any,
        attached: bool = False,
        wait: float | None = 30.0,
        heartbeat: float | None = 1.0,
        poison_limit: int = 3,
        nice: int | None = None,
        cpu_affinity: list[int] | None = None,
        **kwargs: Any,
    ) -> ActorRef:
        """Start ``cls(*args, **kwargs)`` as actor ``name`` and return its ref.

        By default it gets its own process; ``attached=True`` runs it as a
        pykka thread here. Arguments must be msgpack-serializable. With
        ``wait`` (seconds) the call returns once the actor serves messages.
        """
        wire.check_name(name)
        if name in self.procs or name in self.attached:
            raise ActorError(f"an actor named {name!r} already exists in this run; pick another name")
        if not (isinstance(cls, type) and issubclass(cls, Actor)):
            raise TypeError(f"spawn() takes an Actor subclass, not {cls!r}")
        self.rt.register(name, {"endpoint": self.rt.endpoint(name), "kind": "attached" if attached else "process"})
        self.order.append(name)
        if attached:
            self._spawn_attached(cls, name, args, kwargs, heartbeat=heartbeat, poison_limit=poison_limit)
            return ActorRef(name)
        spec = self.make_spec(
            cls, name, args, kwargs, heartbeat=heartbeat, poison_limit=poison_limit, nice=nice, cpu_affinity=cpu_affinity
        )
        info = self.start_process(spec)
        if wait:
            self.wait_ready(info, wait)
        return ActorRef(name)

    def wait_ready(self, info: ProcessInfo, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while not info.ready.wait(0.01):
            if info.exited.is_set():
                raise ActorError(
                    f"actor {info.name!r} exited during start (exit code {info.exit_code})"
                    + (f": {info.failure}" if info.failure else "; see its log lines above")
                )
            if time.monotonic() > deadline:
                raise ActorError(f"actor {info.name!r} did not become ready within {timeout} s")

    def _spawn_attached(self, cls: type[Actor], name: str, args: tuple, kwargs: dict, **opts: Any) -> None:
        actor = cls(*args, **kwargs)
        wrapper = _PykkaWrapper.start(actor)
        started = threading.Event()
        box: list[Any] = []

        def io() -> None:
            loop = Loop()
            self.rt.adopt_loop(loop)

            class _Forward(Actor):
                def on_receive(self, message: Any) -> Any:
                    return wrapper.ask(message)

            host = ActorHost(self.rt, loop, name, _Forward(), heartbeat=opts["heartbeat"], poison_limit=opts["poison_limit"])
            actor.context = host.actor.context
            box.append(host)
            wrapper.ask(("__start__",))
            started.set()
            try:
                host.serve()
            finally:
                host.close()

        t = threading.Thread(target=io, name=f"attached-{name}", daemon=True)
        t.start()
        started.wait(10)
        self.attached[name] = (wrapper, t)
        if box:
            self._attached_hosts[name] = box[0]

    # -- control ------------------------------------------------------------
    def ref(self, name: str) -> ActorRef:
        """The ref of actor ``name``; ActorNotFound if there is none."""
        self.rt.lookup(name)
        return ActorRef(name)

    def signal(self, name: str, sig: int) -> None:
        """Send a signal to actor ``name``'s process (tests and the supervisor use it)."""
        info = self.procs[name]
        if info.pid is not None and info.method == "spawn" and not info.exited.is_set():
            with contextlib.suppress(ProcessLookupError):
                os.kill(info.pid, sig)
        elif info.pid is not None and self.forkserver_failure is None and not info.exited.is_set():
            self.forkserver.send(["kill", info.pid, int(sig)])

    def ctrl(self, name: str, cmd: str, *args: Any, timeout: float = 5.0) -> Any:
        """Run control command ``cmd`` in actor ``name`` (e.g. "ping", "stats") and return its answer."""
        return ActorRef(name).control(cmd, *args, timeout=timeout).get()

    def stop(self, name: str, timeout: float = 5.0, *, unregister: bool = True) -> int | None:
        """Stop ``name`` cleanly (its ``on_stop`` runs), killing it after ``timeout``."""
        if name in self.attached:
            wrapper, thread = self.attached.pop(name)
            host = self._attached_hosts.pop(name, None)
            if host is not None:
                host.loop.call_soon_threadsafe(host.request_stop)
            thread.join(timeout)
            wrapper.stop()
            if unregister:
                self.rt.unregister(name)
            return 0
        info = self.procs.get(name)
        if info is None:
            return None
        if not info.exited.is_set() and info.pid is not None:
            try:
                self.ctrl(name, "stop", timeout=min(timeout, 2.0))
            except Exception:
                self.signal(name, signal.SIGTERM)
            if not info.exited.wait(timeout):
                self.signal(name, signal.SIGKILL)
                info.exited.wait(5)
        self.rt.on_client(lambda: self.rt.drop_link(name))
        if unregister:
            self.rt.unregister(name)
            self.procs.pop(name, None)
            if name in self.order:
                self.order.remove(name)
        return info.exit_code

    def shutdown(self, timeout: float = 5.0) -> None:
        """Stop every actor in reverse start order and remove the run's traces."""
        if self.closed:
            return
        self.closed = True
        for hook in self.before_shutdown:
            with contextlib.suppress(Exception):
                hook()
        for name in reversed(list(self.order)):
            with contextlib.suppress(Exception):
                self.stop(name, timeout)
        self.rt.on_client(lambda: self.loop.remove(self.forkserver.fileno()))
        self._reap_spawned(timeout)
        self.forkserver.close()
        self.rt.close()
        set_current(None)
        sweep(shm_prefix(self.run_id))
        shutil.rmtree(self.run_dir, ignore_errors=True)

    def _reap_spawned(self, timeout: float) -> None:
        """No spawned process (a standby nobody stopped) outlives the run: SIGTERM, then SIGKILL."""
        entries = self.rt.on_client(lambda: [(proc, info.standby) for proc, info, _ in self._spawned.values()])
        procs = [proc for proc, _ in entries]
        for proc, standby in entries:
            with contextlib.suppress(ProcessLookupError):
                # A standby holds nothing yet (and may be busy in on_standby with SIGTERM blocked).
                proc.send_signal(signal.SIGKILL if standby else signal.SIGTERM)
        deadline = time.monotonic() + timeout
        for proc in procs:
            try:
                proc.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        # Reaped here; their exits (pidfd closed, files removed, listeners told) on the IO thread.
        def reaped() -> None:
            for pid in list(self._spawned):
                self._on_spawned_exit(pid)

        self.rt.on_client(reaped)

    def __enter__(self) -> ActorSystem:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()


class _PykkaWrapper(pykka.ThreadingActor):
    """Runs a user's Actor as a pykka thread (the attached mode)."""

    def __init__(self, actor: Actor) -> None:
        super().__init__()
        self.actor = actor

    def on_receive(self, message: Any) -> Any:
        if message == ("__start__",):
            self.actor.on_start()
            return None
        return self.actor.on_receive(message)

    def on_stop(self) -> None:
        self.actor.on_stop()

    def on_failure(self, exc_type: Any, exc: Any, tb: Any) -> None:
        self.actor.on_failure(exc_type, exc, tb)
