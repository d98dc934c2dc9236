"""The bench's own actors for the ``chaos`` case: two streams to check, and faults on request.

- :class:`NumberSource` numbers messages 0, 1, 2, ... and sends each twice: as a
  tell to :class:`NumberSink` (at-least-once) and on the ``keep="all"`` topic
  ``chaos_numbers``, 10 every 50 ms from a timer callback that works 20 ms
  between the two halves of each batch (a sender busy in a callback while its
  receiver restarts: issue 11's first defect). It keeps ``{"acked": W}`` in its snapshot, W being the
  highest number whose tell the sink acknowledged, and a new incarnation
  resumes at W + 1: a number is never skipped because the source died.
- :class:`NumberSink` appends each number it handles to a file of its own
  incarnation (``sink-<pid>.log``: ``T n source_pid`` for a tell, ``S n
  source_pid`` for the topic, preceded by ``D total`` when its subscription's
  count of dropped messages grew), written with one ``write`` each, so a
  SIGKILL loses no record of a handled message.
- :class:`FrameSource` publishes a 640x480 RGB :class:`~embagents.msgs.Image`
  (shared memory) at 15 Hz, every pixel set to its frame number mod 251;
  :class:`FrameSink` (``keep="latest"``) records each frame and whether its
  pixels match its number (``frames-<pid>.log``).

Every one of them is a :class:`FaultTarget`: a told :class:`Fault` makes it
raise or allocate past its ``max_rss_mb``, once per fault id (a marker file
records that it fired, so the tell redelivered to the next incarnation does
nothing and is not a poison message).

Example::

    >>> Fault("raise", 7)
    Fault(kind='raise', fault_id=7, mb=0)
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Any

import attrs
import numpy as np

from actors import Actor
from actors.codec import message
from embagents.msgs import Image
from embagents.realtime import next_deadline

__all__ = [
    "FRAME_HZ",
    "FRAME_SHAPE",
    "NUMBERS_TOPIC",
    "Fault",
    "FaultTarget",
    "FrameSink",
    "FrameSource",
    "InjectedFault",
    "NumberSink",
    "NumberSource",
]

NUMBERS_TOPIC = "chaos_numbers"
FRAMES_TOPIC = "chaos_frames"
SINK = "chaos_sink"
FRAME_SHAPE = (480, 640, 3)
FRAME_HZ = 15.0
#: Numbers sent per tick, and seconds between ticks: 200 numbers/s on each channel. Each tick
#: works WORK_S between its two halves, as a handler processing a frame would.
BATCH, TICK_S, WORK_S = 10, 0.05, 0.02


class InjectedFault(RuntimeError):
    """What a :class:`FaultTarget` raises on a ``Fault("raise", ...)``."""


@message("embagents.bench/Fault")
@attrs.define
class Fault:
    """A fault to act out: ``kind`` is "raise" or "alloc" (``mb`` MiB, touched)."""

    kind: str
    fault_id: int
    mb: int = 0


class FaultTarget(Actor):
    """An actor that acts out a told :class:`Fault` once; ``workdir`` holds the markers and records."""

    def __init__(self, workdir: str) -> None:
        self.workdir = workdir
        self._ballast: np.ndarray | None = None

    def every(self, period: float, fn: Callable[[], bool]) -> None:
        """Call ``fn`` every ``period`` s on absolute deadlines (:mod:`embagents.realtime`) while it returns True."""
        due = time.monotonic()

        def tick() -> None:
            nonlocal due
            if fn():
                due, _ = next_deadline(due, period, time.monotonic())
                self.context.call_later(max(0.0, due - time.monotonic()), tick)

        self.context.call_later(0.0, tick)

    def record_file(self, stem: str) -> int:
        """An append-only file ``<workdir>/<stem>-<pid>.log`` of this incarnation (an fd)."""
        return os.open(os.path.join(self.workdir, f"{stem}-{os.getpid()}.log"), os.O_WRONLY | os.O_CREAT | os.O_APPEND)

    def on_receive(self, message: Any) -> Any:
        if not isinstance(message, Fault):
            raise ValueError(f"{type(self).__name__} takes a Fault, not {message!r}")
        marker = os.path.join(self.workdir, f"fault-{message.fault_id}")
        try:
            os.close(os.open(marker, os.O_WRONLY | os.O_CREAT | os.O_EXCL))
        except FileExistsError:
            return None  # fired before: this is the redelivery to the next incarnation
        if message.kind == "raise":
            raise InjectedFault(f"fault {message.fault_id}: raised on request")
        if message.kind == "alloc":
            # Touched pages count in RSS; the root's 0.5 s sampling sees them and kills us.
            self._ballast = np.ones(message.mb << 20, dtype=np.uint8)
            return None
        raise ValueError(f"unknown fault kind {message.kind!r}; one of: raise, alloc")


class NumberSource(FaultTarget):
    """Sends numbered messages as tells and on a keep-all topic; resumes after its acked watermark."""

    def __init__(self, workdir: str) -> None:
        super().__init__(workdir)
        self.acked = -1

    def snapshot(self) -> dict[str, int]:
        return {"acked": self.acked}

    def restore(self, state: Any) -> None:
        self.acked = int(state["acked"])

    def on_start(self) -> None:
        self.next = self.acked + 1  # numbers after the watermark may not have reached the sink: send them again
        self.unacked: list[int] = []
        self.sink = self.context.ref(SINK)
        self.running = True
        self.fd = self.record_file("source")
        self.every(TICK_S, self._tick)

    def _tick(self) -> bool:
        if not self.running:
            return False
        pid = os.getpid()
        for n in range(self.next, self.next + BATCH):
            if n - self.next == BATCH // 2:
                time.sleep(WORK_S)  # work between two sends: a sink restarting now finds us inside a callback
            self.sink.tell([n, pid])
            self.context.publish(NUMBERS_TOPIC, [n, pid])
            self.unacked.append(n)
        self.next += BATCH
        self._account()
        return True

    def _account(self) -> None:
        # Tells are acknowledged cumulatively and in order: all but the last `backlog` are in.
        done = len(self.unacked) - self.sink.backlog()
        if done > 0:
            self.acked = self.unacked[done - 1]
            del self.unacked[:done]
            os.write(self.fd, f"A {self.acked} {self.next - 1} {time.monotonic():.3f}\n".encode())
            self.context.changed()  # the snapshot now holds the new watermark

    def on_receive(self, message: Any) -> Any:
        if message == "finish":  # stop sending, wait for the acks, answer the watermark
            self.running = False
            self.sink.flush(10.0)
            self._account()
            return {"acked": self.acked, "sent": self.next - 1}
        return super().on_receive(message)

    def on_stop(self) -> None:
        os.close(self.fd)


class NumberSink(FaultTarget):
    """Records every numbered message it handles, by channel, in its incarnation's file."""

    def on_start(self) -> None:
        self.fd = self.record_file("sink")
        self.sub = self.context.subscribe(NUMBERS_TOPIC, self._on_topic, queue_size=100, keep="all")
        self.dropped = 0  # the subscription's count of dropped messages, as last recorded

    def _on_topic(self, msg: Any) -> None:
        line = f"S {msg[0]} {msg[1]}\n"
        if self.sub.dropped != self.dropped:
            # The runtime counts a gap when it reads the frame after it, before that frame's callback: so the
            # count's D line is written before (and with, in one write) the first number past the gap.
            self.dropped = self.sub.dropped
            line = f"D {self.dropped}\n{line}"
        os.write(self.fd, line.encode())

    def on_receive(self, message: Any) -> Any:
        if isinstance(message, list):
            os.write(self.fd, f"T {message[0]} {message[1]}\n".encode())
            return None
        return super().on_receive(message)

    def on_stop(self) -> None:
        os.close(self.fd)


class FrameSource(FaultTarget):
    """Publishes a 640x480 RGB frame at 15 Hz; every pixel is the frame number mod 251."""

    def on_start(self) -> None:
        self.image = Image
        self.frame = np.empty(FRAME_SHAPE, dtype=np.uint8)
        self.k = 0
        self.fd = self.record_file("frames-source")
        self.every(1.0 / FRAME_HZ, self._tick)

    def _tick(self) -> bool:
        self.frame.fill(self.k % 251)
        self.context.publish(FRAMES_TOPIC, self.image(data=self.frame, frame_id=str(self.k)))
        os.write(self.fd, f"P {self.k}\n".encode())
        self.k += 1
        return True

    def on_stop(self) -> None:
        os.close(self.fd)


class FrameSink(FaultTarget):
    """Records each frame it gets and whether its pixels are the ones sent (``ok`` / ``torn``)."""

    def on_start(self) -> None:
        self.fd = self.record_file("frames-sink")
        self.context.subscribe(FRAMES_TOPIC, self._on_frame, queue_size=2, keep="latest")

    def _on_frame(self, img: Any) -> None:
        k = int(img.frame_id)
        d = img.data
        ok = d.shape == FRAME_SHAPE and d[0, 0, 0] == d[240, 320, 1] == d[-1, -1, -1] == k % 251
        os.write(self.fd, f"R {k} {'ok' if ok else 'torn'}\n".encode())

    def on_stop(self) -> None:
        os.close(self.fd)
