"""Actor classes for the supervisor tests (top level, imported before systems start)."""

from __future__ import annotations

import ctypes
import os
import signal
import time
from typing import Any

import attrs

from actors import Actor, message


def _append(path: str, line: str) -> None:
    # One write() per line with O_APPEND: survives SIGKILL, never interleaves.
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600)
    try:
        os.write(fd, f"{line}\n".encode())
    finally:
        os.close(fd)


class Echo(Actor):
    """Answers; on request crashes in every way a real actor can."""

    def __init__(self, log: str | None = None) -> None:
        self.log = log

    def on_start(self) -> None:
        if self.log:
            _append(self.log, f"start {self.name} {os.getpid()}")

    def on_stop(self) -> None:
        if self.log:
            _append(self.log, f"stop {self.name} {os.getpid()}")

    def on_receive(self, message: Any) -> Any:
        if message == "pid":
            return os.getpid()
        if message == "crash":
            raise ValueError("asked to crash")
        if message == "stop":
            self.context.stop()
            return "stopping"
        if message == "sigterm":  # a real death by SIGTERM (the runtime's handler would exit cleanly)
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGTERM)
        if message == "segv":
            ctypes.string_at(0)  # a real SIGSEGV from native code
        if message == "hang":
            sum(range(10**13))  # one C call holding the GIL: no heartbeat, no signal handler
        if message == "spin":
            end = time.monotonic() + 60
            while time.monotonic() < end:
                pass
        if message == "alloc":
            chunks = []
            for _ in range(150):  # up to 1.5 GB, touched so it counts in RSS
                chunks.append(b"x" * 10_000_000)
                time.sleep(0.02)
        if isinstance(message, list) and message and message[0] == "exit":
            os._exit(message[1])
        return message


class FailStart(Actor):
    """Fails in on_start while ``flag`` exists (or always, without a flag)."""

    def __init__(self, flag: str | None = None) -> None:
        self.flag = flag

    def on_start(self) -> None:
        if self.flag is None or os.path.exists(self.flag):
            raise RuntimeError("cannot start")

    def on_receive(self, message: Any) -> Any:
        return message


class SlowStop(Actor):
    """Takes ``seconds`` to stop cleanly (or ignores SIGTERM with ``ignore_term``); creates ``stopping`` as it begins."""

    def __init__(self, seconds: float, log: str | None = None, ignore_term: bool = False,
                 stopping: str | None = None) -> None:
        self.seconds = seconds
        self.log = log
        self.ignore_term = ignore_term
        self.stopping = stopping

    def on_start(self) -> None:
        if self.ignore_term:
            signal.signal(signal.SIGTERM, signal.SIG_IGN)

    def on_stop(self) -> None:
        if self.stopping:
            open(self.stopping, "w").close()
        time.sleep(self.seconds)
        if self.log:
            _append(self.log, f"stopped {self.name}")

    def on_receive(self, message: Any) -> Any:
        return os.getpid() if message == "pid" else message


def _die_if_decoded_elsewhere(pid: int) -> int:
    if pid != os.getpid():
        os.kill(os.getpid(), signal.SIGKILL)  # as a decoder that crashes on a frame would
    return pid


@message("tests/DiesWhenDecoded")
@attrs.define
class DiesWhenDecoded:
    """Kills any process but its sender ``pid`` that decodes it (its class is built while the frame decodes)."""

    pid: int = attrs.field(converter=_die_if_decoded_elsewhere)


class Recorder(Actor):
    """Writes every message it handles to ``path``; "poison" crashes it every time."""

    def __init__(self, path: str, delay: float = 0.0) -> None:
        self.path = path
        self.delay = delay

    def on_receive(self, message: Any) -> Any:
        if message == "poison":
            raise ValueError("poison")
        if message == "pid":
            return os.getpid()
        if self.delay:
            time.sleep(self.delay)
        _append(self.path, str(message))
        return None


class Managed(Actor):
    """Records its lifecycle hooks; keeps a counter through snapshots."""

    def __init__(self, log: str, fail_activate: bool = False) -> None:
        self.log = log
        self.fail_activate = fail_activate
        self.count = 0
        self.restored: Any = None

    def on_start(self) -> None:
        _append(self.log, f"on_start count={self.count}")

    def on_configure(self) -> None:
        _append(self.log, "on_configure")

    def on_activate(self) -> bool:
        _append(self.log, "on_activate")
        return not self.fail_activate

    def on_deactivate(self) -> None:
        _append(self.log, "on_deactivate")

    def on_cleanup(self) -> None:
        _append(self.log, "on_cleanup")

    def on_shutdown(self) -> None:
        _append(self.log, "on_shutdown")

    def snapshot(self) -> dict[str, Any]:
        return {"count": self.count}

    def restore(self, state: dict[str, Any]) -> None:
        self.count = state["count"]
        self.restored = state

    def on_receive(self, message: Any) -> Any:
        if message == "pid":
            return os.getpid()
        if message == "count":
            return self.count
        if message == "restored":
            return self.restored
        if message == "die":
            os.kill(os.getpid(), signal.SIGKILL)
        self.count += 1
        return self.count


class EventSink(Actor):
    """Subscribes to the supervisor's event topic and keeps what it hears."""

    def on_start(self) -> None:
        self.seen: list[dict[str, Any]] = []
        self.context.subscribe("_supervisor.events", self.seen.append, keep="all", queue_size=1000)

    def on_receive(self, message: Any) -> Any:
        return self.seen


class BurstSender(Actor):
    """Inside ONE handler, tells ``target`` the numbers 0..n-1 in batches with pauses."""

    def on_receive(self, message: Any) -> Any:
        target, n, batch, pause = message
        ref = self.context.ref(target)
        for i in range(n):
            ref.tell(i)
            if (i + 1) % batch == 0:
                time.sleep(pause)  # still inside the handler: the sender's loop does not run
        return n


class SlowConfigure(Managed):
    """A Managed actor whose ``on_configure`` takes ``configure_s`` (a CUDA model's start, say).

    A warm standby does that work in ``on_standby``; the configure of its takeover then finds it done.
    """

    def __init__(self, log: str, configure_s: float = 5.0) -> None:
        super().__init__(log)
        self.configure_s = configure_s
        self.ready_ahead = False

    def on_standby(self) -> None:
        time.sleep(self.configure_s)
        self.ready_ahead = True
        _append(self.log, f"on_standby {os.getpid()}")

    def on_configure(self) -> None:
        if not self.ready_ahead:
            time.sleep(self.configure_s)
        _append(self.log, f"on_configure {os.getpid()} ahead={self.ready_ahead}")


class KeepAllRecorder(SlowConfigure):
    """A SlowConfigure with a ``keep="all"`` input: appends ``<pid> <n>`` to ``out`` for each number on ``topic``.

    One write per number: a SIGKILL loses no record of a number it handled.
    """

    def __init__(self, log: str, configure_s: float, topic: str, out: str, die_on: int = -1) -> None:
        super().__init__(log, configure_s)
        self.topic, self.out, self.die_on = topic, out, die_on

    def on_start(self) -> None:
        super().on_start()
        self.sub = self.context.subscribe(self.topic, self._on, queue_size=100, keep="all")

    def _on(self, n: int) -> None:
        if n == self.die_on and not os.path.exists(self.out + ".died"):  # once: taken, never finished
            _append(self.out + ".died", str(n))
            os.kill(os.getpid(), signal.SIGKILL)
        _append(self.out, f"{os.getpid()} {n}")

    def on_receive(self, message: Any) -> Any:
        if message == "sub":
            return self.sub.stats()
        return super().on_receive(message)
