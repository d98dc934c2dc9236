"""Actor classes used by the tests (top level, imported before systems start)."""

from __future__ import annotations

import os
import threading
import time
from typing import Any

import numpy as np

from actors import Actor, Deferred


class Echo(Actor):
    def on_receive(self, message: Any) -> Any:
        if isinstance(message, str) and message == "raise":
            raise ValueError("asked to raise")
        if isinstance(message, str) and message == "pid":
            return os.getpid()
        return message


class Deferrer(Actor):
    """Answers "hold" later, when ["release", value] or "fail" comes; "later" from a thread of its own.

    Anything else: how many answers it holds."""

    def on_start(self) -> None:
        self.held: list[Deferred] = []

    def on_receive(self, message: Any) -> Any:
        if message == "hold":
            self.held.append(Deferred())
            return self.held[-1]
        if message == "later":
            answer = Deferred()
            threading.Timer(0.2, answer.resolve, ["from a thread"]).start()
            return answer
        if message == "fail" or (isinstance(message, list) and message[0] == "release"):
            held, self.held = self.held, []
            for answer in held:
                if message == "fail":
                    answer.fail(ValueError("no luck"))
                else:
                    answer.resolve(message[1])
        return len(self.held)


class Counter(Actor):
    def on_start(self) -> None:
        self.seen: list[int] = []

    def on_receive(self, message: Any) -> Any:
        if message == "seen":
            return self.seen
        if message == "hang":
            time.sleep(60)
        self.seen.append(message)
        return None


class Forwarder(Actor):
    """Asks another actor from inside its handler (the loop-thread path)."""

    def on_receive(self, message: Any) -> Any:
        target, payload = message
        return self.context.ref(target).ask(payload, timeout=5).get()


class Holder(Actor):
    """Keeps the arrays it receives (views on the sender's shared memory)."""

    def on_start(self) -> None:
        self.kept: list[np.ndarray] = []

    def on_receive(self, message: Any) -> Any:
        if isinstance(message, str) and message == "sum":
            return [int(a.sum()) for a in self.kept]
        if isinstance(message, str) and message == "drop":
            self.kept.clear()
            return None
        self.kept.append(message)
        return len(self.kept)


class Publisher(Actor):
    def on_receive(self, message: Any) -> Any:
        topic, payload = message
        self.context.publish(topic, payload)
        return None


class Subscriber(Actor):
    def __init__(self, topic: str, queue_size: int = 10, keep: str = "latest") -> None:
        self.topic, self.queue_size, self.keep = topic, queue_size, keep

    def on_start(self) -> None:
        self.got: list[Any] = []
        self.context.subscribe(self.topic, self.got.append, queue_size=self.queue_size, keep=self.keep)

    def on_receive(self, message: Any) -> Any:
        if message == "got":
            out = [g if not isinstance(g, np.ndarray) else ["array", g.shape, int(g[-1])] for g in self.got]
            return out
        return None


class Keeper(Actor):
    """Asks an echo with large arrays from inside its handler and keeps every reply."""

    def on_receive(self, message: Any) -> Any:
        target, n = message
        ref = self.context.ref(target)
        held = [ref.ask(np.full(1 << 20, i, np.uint8), timeout=5).get() for i in range(n)]
        return [int(h[0]) for h in held]


class Looper(Actor):
    """Asks an echo ``n`` times with a large array from inside its handler, keeping only the last reply."""

    def on_receive(self, message: Any) -> Any:
        target, n = message
        ref = self.context.ref(target)
        reply = None
        for i in range(n):
            reply = ref.ask(np.full(1 << 20, i % 251, np.uint8), timeout=5).get()
        return int(reply[0]) if reply is not None else None


class Burst(Actor):
    """Publishes 0..n-1 on a topic from inside one handler, as fast as the topic takes them."""

    def on_receive(self, message: Any) -> Any:
        topic, n = message
        t0 = time.monotonic()
        longest = 0.0
        for i in range(n):
            t = time.monotonic()
            self.context.publish(topic, i)
            longest = max(longest, time.monotonic() - t)
        self.total = getattr(self, "total", 0) + n
        return {"seconds": time.monotonic() - t0, "longest_publish": longest, "total": self.total}


class TopicCounter(Actor):
    """Subscribes with a slow callback; reports what it got and its subscription's counts."""

    def __init__(self, topic: str, queue_size: int, keep: str, delay: float) -> None:
        self.args = (topic, queue_size, keep)
        self.delay = delay

    def on_start(self) -> None:
        self.got: list[int] = []
        topic, queue_size, keep = self.args
        self.sub = self.context.subscribe(topic, self._on, queue_size=queue_size, keep=keep)

    def _on(self, msg: int) -> None:
        if self.delay:
            time.sleep(self.delay)
        self.got.append(msg)

    def on_receive(self, message: Any) -> Any:
        if message == "pid":
            return os.getpid()
        if message == "stats":
            return {"got": len(self.got), "distinct": len(set(self.got)), "ordered": self.got == sorted(self.got),
                    "last": self.got[-1] if self.got else None, **self.sub.stats()}
        return None


class FdProbe(Actor):
    """Says what the given fds are in its process: [st_dev, st_ino], or None if closed."""

    def on_receive(self, message: Any) -> Any:
        out: list[Any] = []
        for fd in message:
            try:
                st = os.fstat(fd)
                out.append([st.st_dev, st.st_ino])
            except OSError:
                out.append(None)
        return out


#: Files the root (the test) opened before its fork server: the actor drops them (see FdReuse).
INHERITED: list[Any] = []


class FdReuse(Actor):
    """Opens files until fd ``n`` is in use, drops the root's :data:`INHERITED` files (as a library
    re-initialised after a fork drops its handles), and names the fds it lost (not /dev/null ones)."""

    def on_receive(self, n: Any) -> Any:
        import stat

        mine = [os.open(os.devnull, os.O_RDONLY)]  # numbers up to n in use, as a busy actor's would be
        while mine[-1] < n and len(mine) < 256:
            mine.append(os.open("/proc/self/stat", os.O_RDONLY))
        before = {}
        for name in os.listdir("/proc/self/fd"):
            try:
                before[int(name)] = os.fstat(int(name))
            except OSError:
                pass
        INHERITED.clear()  # the root's file object that owned fd n closes it now
        null = os.stat(os.devnull).st_rdev
        lost = []
        for fd, st in before.items():
            try:
                os.fstat(fd)
            except OSError:
                if not (stat.S_ISCHR(st.st_mode) and st.st_rdev == null):
                    lost.append(fd)
        for fd in mine:
            try:
                os.close(fd)
            except OSError:
                pass
        return lost


class GcProbe(Actor):
    """Says how many objects its garbage collector leaves alone (frozen) and how many it tracks."""

    def on_receive(self, message: Any) -> Any:
        import gc

        return [gc.get_freeze_count(), len(gc.get_objects())]
