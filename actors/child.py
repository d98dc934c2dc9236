"""The main function of an actor process (runs in a child of the fork server)."""

from __future__ import annotations

import contextlib
import faulthandler
import logging
import os
import signal
import socket
import sys
import traceback
from typing import Any

import msgpack
import zmq

from actors.app import app_name
from actors.extension import load_extension
from actors.host import ActorHost, load_class
from actors.loop import Loop
from actors.runtime import Runtime, set_current

__all__ = ["LOG_BACKUPS", "LOG_MAX_BYTES", "TAKE_OVER", "add_log_file", "child_main", "configure_logging", "log_path"]

#: The signal that makes a waiting standby (see :mod:`actors.spawn`) take over.
TAKE_OVER = signal.SIGUSR1

#: Each actor's log file rotates at this size, keeping this many old files (``NAME.log.1`` ...).
LOG_MAX_BYTES = 5 * 1024 * 1024
LOG_BACKUPS = 3
_FORMAT = "%(asctime)s [%(actor)s] %(levelname)s %(name)s: %(message)s"


class _ActorFilter(logging.Filter):
    def __init__(self, actor: str) -> None:
        super().__init__()
        self.actor = actor

    def filter(self, record: logging.LogRecord) -> bool:
        record.actor = getattr(record, "actor", self.actor)
        return True


def configure_logging(actor: str, level: int = logging.INFO) -> None:
    """Every log line of this process says which actor said it."""
    root = logging.getLogger()
    for h in list(root.handlers):
        root.removeHandler(h)
    h = logging.StreamHandler(sys.stderr)
    h.addFilter(_ActorFilter(actor))
    h.setFormatter(logging.Formatter(_FORMAT))
    root.addHandler(h)
    root.setLevel(level)


def log_path(run_dir: str, actor: str) -> str:
    """Where actor ``actor`` of the run at ``run_dir`` writes its log lines."""
    return os.path.join(run_dir, "logs", f"{actor}.log")


def add_log_file(run_dir: str, actor: str) -> None:
    """Also write this process's log lines to :func:`log_path` (rotated; ``embagents logs NAME`` reads it)."""
    from logging.handlers import RotatingFileHandler

    path = log_path(run_dir, actor)
    os.makedirs(os.path.dirname(path), mode=0o700, exist_ok=True)
    h = RotatingFileHandler(path, maxBytes=LOG_MAX_BYTES, backupCount=LOG_BACKUPS)
    h.addFilter(_ActorFilter(actor))
    h.setFormatter(logging.Formatter(_FORMAT))
    logging.getLogger().addHandler(h)


def _notify(rt: Runtime, msg: list[Any]) -> None:
    """Tell the root something (ready, failed) on a short-lived socket."""
    s = rt.ctx.socket(zmq.DEALER)
    s.setsockopt(zmq.LINGER, 1000)
    s.connect(f"ipc://{rt.run_dir}/_root.ctl")
    s.send(msgpack.packb(msg))
    s.close()


def _stand_by(rt: Runtime, name: str, actor: Any) -> bool:
    """A warm standby (see :mod:`actors.spawn`): get ready, say so, wait. True: take over; False: stop.

    The take-over signal and SIGTERM were blocked before any thread started, so one sent
    while ``on_standby`` still runs waits for the ``sigwait`` below.
    """
    actor.on_standby()
    _notify(rt, ["standby", name, os.getpid()])
    sig = signal.sigwait({TAKE_OVER, signal.SIGTERM})
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {TAKE_OVER, signal.SIGTERM})
    return sig == TAKE_OVER


def child_main(spec: dict[str, Any]) -> None:
    """Build the actor described by ``spec``, serve it, and exit with a status that says how it ended."""
    name = spec["name"]
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if faulthandler.is_enabled():
        # Its fd is the root's copy of stderr, closed by the fork server: the next file this process
        # opens (its log) would get that number, and a crash would write there. Point it at our stderr.
        faulthandler.enable(sys.stderr, all_threads=True)
    configure_logging(name, spec.get("log_level", logging.INFO))
    with contextlib.suppress(OSError):  # a log file is a help, not a condition to run
        add_log_file(spec["run_dir"], name)
    with contextlib.suppress(Exception):
        import setproctitle

        setproctitle.setproctitle(f"{app_name()}:{name}")
    if spec.get("nice"):
        os.nice(int(spec["nice"]))
    if spec.get("cpu_affinity"):
        os.sched_setaffinity(0, spec["cpu_affinity"])
    rt = Runtime(spec["run_dir"], spec["run_id"])
    set_current(rt)
    loop = Loop()
    rt.adopt_loop(loop)
    host = None
    try:
        cls = load_class(spec["cls"])
        actor = cls(*spec.get("args", ()), **spec.get("kwargs", {}))
        if spec.get("standby") and not _stand_by(rt, name, actor):
            rt.close()
            os._exit(0)
        extensions = [(load_extension(path), dict(config)) for path, config in spec.get("extensions", ())]
        host = ActorHost(
            rt, loop, name, actor, heartbeat=spec.get("heartbeat"), poison_limit=spec.get("poison_limit", 3),
            extensions=extensions,
        )
        # SIGTERM asks for a clean stop; the wakeup socket interrupts a blocked poll.
        rsock, wsock = socket.socketpair()
        rsock.setblocking(False)
        wsock.setblocking(False)
        signal.set_wakeup_fd(wsock.fileno())
        signal.signal(signal.SIGTERM, lambda *_: host.request_stop())

        def drain() -> None:
            with contextlib.suppress(BlockingIOError):
                rsock.recv(512)

        loop.add(rsock.fileno(), drain)
        host.start()
        _notify(rt, ["ready", name, os.getpid(), host.incarnation])
        host.serve()
    except BaseException as exc:  # the one sender of the "failed" note: on_start, extensions, a told message
        text = traceback.format_exc()
        logging.getLogger("actors").error("actor crashed: %s\n%s", exc, text)
        with contextlib.suppress(Exception):
            _notify(rt, ["failed", name, os.getpid(), f"{type(exc).__name__}: {exc}"])
        with contextlib.suppress(Exception):
            rt.pool.close()
        with contextlib.suppress(Exception):
            rt.ctx.destroy(linger=500)  # lets the note above leave before we exit
        os._exit(1)
    try:
        host.stop()
    finally:
        host.close()
        rt.close()
    os._exit(0)
