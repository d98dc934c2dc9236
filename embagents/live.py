"""A Python client of a running system: one connection for many calls, publishes and subscriptions.

A script that drives a running system (``embagents supervise system.py``)
through ``embagents call`` pays an interpreter start per command; a
:class:`LiveRun` connects once. :func:`connect` finds the run as the CLI
does (``run``: run id, system name or pid; default: the only live run), and
the CLI's ``call``, ``publish``, ``status`` and ``topic echo`` go through it.

- ``call(component, method, *args, **kwargs)``: the component's action, in
  its actor; returns what it returned (JSON-able values as they are, others
  as their ``repr``).
- ``publish(topic, data, **fields)``: a message on a topic, published by the root.
- ``subscribe(topic, callback)``: ``callback(msg)`` for each message, on this
  process's IO thread; ``echo(topic, count=, timeout=)``: the messages as an
  iterator. Both keep-latest: a slow reader drops (counted), never slows a publisher.
- ``status()``: the root's status answer (``rows``: one per actor, as
  ``embagents status --json``); ``wait_ready()``: until every actor runs and
  every managed one is active; ``topics()``; ``restart(name)``; ``stop()``.

Every request carries its deadline: one that times out here is never carried
out later by the run. Errors are :class:`supervisor.client.ControlError`,
whose message is one line; ``err.reply.get("traceback")`` holds a failed
action's remote traceback.

Example (``EMBAGENTS_KEEP_RUNNING=1 embagents supervise examples/chat.py`` in another terminal)::

    from embagents.live import connect

    with connect() as run:
        run.wait_ready()
        print([(r["name"], r["pid"], r["lifecycle"]) for r in run.status()["rows"]])
        print(run.call("llm", "answer", "What is the capital of Italy?"))
        answers = run.echo("text_out", timeout=60)   # subscribed now: nothing published from here on is missed
        run.publish("text_in", "What is the capital of Spain?")
        for chunk in answers:
            print(chunk.data, end="", flush=True)
            if chunk.done:
                break
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Iterator
from types import TracebackType
from typing import Any

from actors.runtime import Runtime
from actors.topics import Subscription
from supervisor.client import ControlClient, ControlError, pick_run

__all__ = ["LiveRun", "Messages", "Subscribed", "connect", "find_topic", "is_ready"]


def connect(run: str | None = None, *, timeout: float = 5.0) -> LiveRun:
    """The live run ``run`` (run id, system name or pid; default: the only one); ``timeout``: per request."""
    return LiveRun(run, timeout=timeout)


def find_topic(rows: list[dict[str, Any]], name: str) -> dict[str, Any]:
    """The row of topic ``name`` (a leading ``/`` is ignored); ControlError naming the run's topics if there is none."""
    name = name.removeprefix("/")
    for r in rows:
        if r["name"] == name:
            return r
    raise ControlError(f"no topic {name!r} in this run; its topics: {', '.join(r['name'] for r in rows)} "
                       "(see `embagents topic list`)")


def _row_ready(row: dict[str, Any]) -> bool:
    if row["status"] == "stopped" and row.get("restart") in ("transient", "temporary"):
        return True  # it ended as its restart type allows: done, not pending
    return bool(row["status"] == "running" and row.get("lifecycle") in (None, "active"))


def is_ready(status: dict[str, Any]) -> bool:
    """Whether a status answer says the run is ready.

    Its ``ready`` where the root says it; else: every actor running and every
    managed one active (a transient or temporary child that ended is done, not pending).
    """
    if "ready" in status:
        return bool(status["ready"])
    return all(_row_ready(r) for r in status["rows"])


class Subscribed:
    """A subscription of a :class:`LiveRun`: ``received``, ``dropped``; ``close()`` ends it."""

    def __init__(self, rt: Any, sub: Any) -> None:
        self._rt, self._sub = rt, sub
        self.closed = False

    @property
    def received(self) -> int:
        return int(self._sub.received)

    @property
    def dropped(self) -> int:
        """Messages lost before the callback (a publisher's high-water mark, a full queue)."""
        return int(self._sub.dropped)

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._rt.on_client(self._sub.close)  # its socket belongs to the IO thread


class Messages:
    """The messages of one topic as an iterator (:meth:`LiveRun.echo`); ``dropped`` counts those lost."""

    def __init__(self, sub: Subscribed, box: queue.Queue[Any], overflow: list[int], count: int | None,
                 timeout: float | None) -> None:
        self.sub, self._box, self._overflow = sub, box, overflow
        self._left = count
        self._end = None if timeout is None else time.monotonic() + timeout

    @property
    def dropped(self) -> int:
        return self.sub.dropped + self._overflow[0]

    def __iter__(self) -> Iterator[Any]:
        return self

    def __next__(self) -> Any:
        if self._left is not None and self._left <= 0:
            self.close()
            raise StopIteration
        try:
            wait = None if self._end is None else max(0.0, self._end - time.monotonic())
            msg = self._box.get(timeout=wait)
        except queue.Empty:
            self.close()
            raise StopIteration from None
        if self._left is not None:
            self._left -= 1
        return msg

    def close(self) -> None:
        self.sub.close()

    def __enter__(self) -> Messages:
        return self

    def __exit__(self, *exc: type[BaseException] | BaseException | TracebackType | None) -> None:
        self.close()


class LiveRun:
    """A connection to a live run (see the module docs); safe to share between threads; close it when done."""

    def __init__(self, run: str | None = None, *, timeout: float = 5.0) -> None:
        self.info = pick_run(run)
        self.run_id: str = self.info["run_id"]
        self.system: str = self.info.get("system", "")
        self.run_dir: str = self.info["run_dir"]
        self.timeout = timeout
        self.control = ControlClient(self.run_dir, timeout)
        self._rt: Any = None
        self._subs: list[Subscribed] = []
        self._lock = threading.Lock()

    def __repr__(self) -> str:
        return f"<LiveRun {self.system!r} run {self.run_id} pid {self.info.get('pid')}>"

    def request(self, msg: dict[str, Any], timeout: float | None = None) -> dict[str, Any]:
        """One control request (see :mod:`supervisor.control`); the root's answer."""
        return self.control.request(msg, timeout)

    # -- the control commands --------------------------------------------------
    def status(self) -> dict[str, Any]:
        """``{"system", "run_id", "pid", "uptime", "rows"}`` (rows as ``embagents status --json``)."""
        return self.request({"cmd": "status"})

    def topics(self, *, rates: bool = False) -> list[dict[str, Any]]:
        """The run's topics (``embagents topic list --json``); ``rates`` measures them (half a second)."""
        return list(self.request({"cmd": "topics", "rates": rates}, max(self.timeout, 2.0) if rates else None)["topics"])

    def topic(self, name: str) -> dict[str, Any]:
        """The row of topic ``name``; ControlError naming the run's topics if it has none."""
        return find_topic(self.topics(), name)

    def call(self, component: str, method: str, *args: Any, timeout: float = 60.0, **kwargs: Any) -> Any:
        """``component.method(*args, **kwargs)`` in its actor; its return value.

        ``timeout``: seconds to wait for it (a call still waiting its turn then
        never runs). A keyword argument of the method named ``timeout`` goes in
        a ``request({"cmd": "call", ..., "kwargs": {...}})``.
        """
        msg = {"cmd": "call", "component": component, "method": method, "args": list(args), "kwargs": kwargs,
               "timeout": timeout}
        return self.request(msg, timeout + 5.0)["result"]  # the root answers a timeout itself, at `timeout`

    def publish(self, topic: str, data: Any = None, /, **fields: Any) -> dict[str, Any]:
        """Publish ``topic``'s message type built from ``fields`` (``data``: its ``data`` field); the root's answer.

        ``run.publish("text_in", "hi")``, ``run.publish("cmd_vel", linear=[0.2, 0, 0])``.
        """
        if data is not None:
            fields["data"] = data
        return self.request({"cmd": "publish", "topic": topic, "fields": fields})

    def restart(self, name: str) -> int | None:
        """Restart actor ``name`` now; its new pid."""
        return self.request({"cmd": "restart", "name": name}).get("pid")

    def stop(self) -> None:
        """Stop the run cleanly (it answers, then stops its actors in reverse order)."""
        self.request({"cmd": "stop"})

    def wait_ready(self, timeout: float = 60.0) -> dict[str, Any]:
        """Wait until the run is ready (:func:`is_ready`); its status then. ControlError naming what is not, after ``timeout``."""
        end = time.monotonic() + timeout
        pause = 0.05
        while True:
            status = self.status()
            if is_ready(status):
                return status
            if time.monotonic() + pause > end:
                waiting = [f"{r['name']} ({r['status']}, {r.get('lifecycle') or '-'})" for r in status["rows"]
                           if not _row_ready(r)]
                raise ControlError(f"run {self.run_id} ({self.system}) not ready within {timeout:g} s; "
                                   f"waiting for: {', '.join(waiting) or 'the root to say so'}", status)
            time.sleep(pause)  # a status look costs the actors a stats ask: a few a second at most
            pause = min(pause * 2, 0.5)

    # -- topics, received here ---------------------------------------------------
    def _runtime(self) -> Any:
        with self._lock:
            if self._rt is None:

                self._rt = Runtime(self.run_dir, self.run_id)
            return self._rt

    def subscribe(self, topic: str, callback: Callable[[Any], None], *, queue_size: int = 100) -> Subscribed:
        """``callback(msg)`` for each message on ``topic`` from now on, on this process's IO thread.

        Keep-latest: a callback slower than the topic loses messages (``dropped``), the publisher goes on.
        A topic the run does not have is a ControlError naming the ones it has.
        """

        name = self.topic(topic)["name"]
        rt = self._runtime()
        sub = Subscribed(rt, rt.on_client(lambda: Subscription(rt, rt.client_loop(), name, callback,
                                                               queue_size=queue_size, keep="latest")))
        with self._lock:
            self._subs = [s for s in self._subs if not s.closed] + [sub]
        return sub

    def echo(self, topic: str, *, count: int | None = None, timeout: float | None = None,
             queue_size: int = 100) -> Messages:
        """The messages on ``topic`` from now on: ``count`` of them, or those within ``timeout`` seconds.

        Subscribed when this returns. Up to ``queue_size`` wait for the reader; more are dropped (counted).
        """
        box: queue.Queue[Any] = queue.Queue(maxsize=queue_size)
        overflow = [0]

        def keep(msg: Any) -> None:
            try:
                box.put_nowait(msg)
            except queue.Full:
                overflow[0] += 1

        return Messages(self.subscribe(topic, keep, queue_size=queue_size), box, overflow, count, timeout)

    def close(self) -> None:
        """Close the connection and this process's runtime (its subscriptions end)."""
        self.control.close()
        with self._lock:
            rt, subs, self._rt, self._subs = self._rt, self._subs, None, []
        for sub in subs:
            sub.close()  # their marks go: publishers stop sending here
        if rt is not None:
            rt.close()

    def __enter__(self) -> LiveRun:
        return self

    def __exit__(self, *exc: type[BaseException] | BaseException | TracebackType | None) -> None:
        self.close()
