"""A terminal's seat in a live run: its topics, and subscriptions that never slow it.

:func:`run_topics` asks the root for the run's topics; :func:`find_topic`
names the known ones when a name is not among them. :class:`Attached` is a
runtime of this process inside the run's directory: its subscriptions are
``keep="latest"`` with a small queue, so a terminal that stops reading loses
messages (counted) and never holds a publisher back.

Example::

    with Attached(pick_run()) as seat:
        seat.subscribe("camera/image", print)
        seat.loop.run(timeout=5)
"""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Callable, Iterator
from types import TracebackType
from typing import Any

from actors.loop import Loop
from actors.runtime import Runtime
from actors.topics import Subscription
from embagents.live import find_topic
from supervisor.client import pick_run, request

__all__ = ["Attached", "find_topic", "interrupted_by_sigterm", "run_topics"]


def run_topics(run: str | None = None, timeout: float = 5.0) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """``(run, topic rows)`` of the live run ``run`` (see :mod:`embagents.tools.root`)."""
    found = pick_run(run)
    return found, request(found["run_dir"], {"cmd": "topics"}, timeout)["topics"]


def _interrupt(*_: Any) -> None:
    raise KeyboardInterrupt  # a signal does not end a poll; an exception does


@contextlib.contextmanager
def interrupted_by_sigterm() -> Iterator[None]:
    """Within it, SIGTERM raises KeyboardInterrupt as Ctrl-C does (a terminal's tool ends the same either way)."""
    old = signal.signal(signal.SIGTERM, _interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


class Attached:
    """This process's runtime in the run ``run`` (a :func:`supervisor.client.pick_run` entry)."""

    def __init__(self, run: dict[str, Any]) -> None:
        self.rt = Runtime(run["run_dir"], run["run_id"])
        self.loop = Loop()
        self.subs: list[Any] = []

    def subscribe(self, topic: str, callback: Callable[[Any], None], queue_size: int = 100) -> Any:
        """A ``keep="latest"`` subscription (the terminal drops, the publisher goes on).

        The queue holds a burst; a terminal that stops reading fills it, and then the
        publisher drops for it (its high-water mark) without waiting.
        """

        sub = Subscription(self.rt, self.loop, topic, callback, queue_size=queue_size, keep="latest")
        self.subs.append(sub)
        return sub

    def run(self, until: Callable[[], bool] | None = None, timeout: float | None = None) -> None:
        """Serve the subscriptions until ``until()``, ``timeout``, Ctrl-C or SIGTERM."""
        with interrupted_by_sigterm():
            try:
                self.loop.run(until=until, timeout=timeout)
            except KeyboardInterrupt:
                pass

    def __enter__(self) -> Attached:
        return self

    def __exit__(self, *exc: type[BaseException] | BaseException | TracebackType | None) -> None:
        for s in self.subs:
            s.close()  # its mark goes: publishers stop sending to us
        self.loop.close()
        self.rt.close()
