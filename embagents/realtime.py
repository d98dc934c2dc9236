"""Timing for control loops: the one rate rule, and a loop thread's scheduling priority.

:func:`next_deadline` is the one rate rule of embagents: a component's rate trigger and the
manager loop both follow it.

Deadlines are absolute: tick *n* is due at ``start + n * period``, so the
rate does not drift. When a tick ends after the next one was due, that next
tick runs at once (late, but not lost), and the deadlines it overran beyond
it are dropped (no burst of catch-up ticks), so the phase is kept. rclpy's
timers behave the same way.

Example::

    >>> next_deadline(1.0, 0.25, now=1.1)    # on time: the next tick is due at 1.25
    (1.25, False)
    >>> next_deadline(1.0, 0.25, now=1.8)    # overran: run at once (1.75 <= now), then 2.0, 2.25, ...
    (1.75, True)

Scheduling priority, real-time where the machine allows it: a robot's control loop (the arm's driver, a VLA's action loop) should be
served first when it wakes. :func:`raise_priority` gives the calling thread
real-time FIFO scheduling, else nice -10, else leaves it as it is, and says
which it got. On Linux both act on the calling thread only: a neighbour in the
same process keeps its normal priority (though not, in Python, its own GIL).
Components offer it as ``realtime=True`` in their config (:class:`~embagents.components.Sim`,
:class:`~embagents.components.VLA`).

Example::

    >>> raise_priority() in ("SCHED_FIFO 10", "nice -10", "normal")   # doctest: +SKIP
    True
"""

from __future__ import annotations

import math
import os
import threading

__all__ = ["next_deadline", "raise_priority"]


def next_deadline(deadline: float, period: float, now: float) -> tuple[float, bool]:
    """The deadline of the tick after the one due at ``deadline``, and whether that one overran.

    When it overran (``now`` past the next deadline), the result is the
    latest deadline on the phase that is not after ``now``: due at once.
    """
    nxt = deadline + period
    if now <= nxt:
        return nxt, False
    return nxt + math.floor((now - nxt) / period) * period, True

def _threads(whole_process: bool) -> list[int]:
    if not whole_process:
        return [threading.get_native_id()]
    try:
        return [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        return [threading.get_native_id()]


def raise_priority(fifo: int = 10, nice: int = -10, whole_process: bool = False) -> str:
    """Real-time FIFO at ``fifo`` for the calling thread, else ``nice``, else nothing; returns what it got.

    ``whole_process``: every thread of this process as it is now (a component's process: its loop
    and the messaging library's I/O threads, which carry its commands).
    """
    tids = _threads(whole_process)
    try:
        for tid in tids:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(fifo))
        return f"SCHED_FIFO {fifo}"
    except (OSError, AttributeError):  # no CAP_SYS_NICE (or RLIMIT_RTPRIO), or not Linux
        pass
    try:
        for tid in tids:
            os.setpriority(os.PRIO_PROCESS, tid, nice)
        return f"nice {nice}"
    except OSError:
        return "normal"
