"""The actors the benchmark runs on our runtime (top level, so actor processes can load them).

Every measuring loop runs *inside* an actor process: a :class:`Pinger`
handler asks an :class:`Echo` in another process, so the asking thread is
the actor's own IO thread and drives the socket directly (the fast path).
The root process only starts a run and collects the numbers.

Example::

    >>> from actors import ActorSystem
    >>> with ActorSystem() as system:                                # doctest: +SKIP
    ...     system.spawn(Echo, "echo")
    ...     pinger = system.spawn(Pinger, "pinger")
    ...     lat_ns = pinger.ask(("ask", "echo", 64, 10, 100), timeout=30).get()
    >>> len(lat_ns)                                                  # doctest: +SKIP
    100
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from actors import Actor
from embagents.bench.registry import payload

__all__ = ["Counter", "Echo", "Pinger", "TopicSink", "TopicSource"]

_ASK_TIMEOUT = 30.0


def _nbytes(value: Any) -> int:
    return value.nbytes if isinstance(value, np.ndarray) else len(value)


class Echo(Actor):
    """Answers every message with the message itself (arrays go back through shared memory).

    >>> Echo().on_receive(b"x")
    b'x'
    """

    def on_receive(self, message: Any) -> Any:
        return message


class Pinger(Actor):
    """Asks another actor in a loop from inside its handler and times each round trip.

    ``("ask", target, size, warmup, n)`` -> int64 array of ``n`` round trips in ns.
    """

    def on_receive(self, message: Any) -> Any:
        cmd, target, size, warmup, n = message
        if cmd != "ask":
            raise ValueError(f"Pinger takes ('ask', target, size, warmup, n), not {cmd!r}")
        ref = self.context.ref(target)
        data = payload(size)
        reply: Any = None
        for _ in range(warmup):
            reply = ref.ask(data, timeout=_ASK_TIMEOUT).get()
        reply = None  # views of shared memory are released when dropped
        out = np.empty(n, dtype=np.int64)
        clock = time.perf_counter_ns
        for i in range(n):
            t0 = clock()
            reply = ref.ask(data, timeout=_ASK_TIMEOUT).get()
            out[i] = clock() - t0
        if _nbytes(reply) != size:
            raise RuntimeError(f"echo answered {_nbytes(reply)} bytes, sent {size}")
        return out


class Counter(Actor):
    """Counts told messages; ``"count"`` (asked) returns the count.

    >>> c = Counter(); c.on_receive(b"x"); c.on_receive("count")
    1
    """

    def __init__(self) -> None:
        self.n = 0

    def on_receive(self, message: Any) -> Any:
        if message == "count":
            return self.n
        self.n += 1
        return None


class Teller(Actor):
    """Tells ``n`` 64-byte messages to ``target`` as fast as it can, then waits until all are handled.

    ``("tell", target, n, rounds)`` -> ``{"call_ns": int64 array (per tell() call, last round),
    "round_s": [seconds from first tell to the last acknowledged, per round]}``.
    """

    def on_receive(self, message: Any) -> Any:
        cmd, target, n, rounds = message
        if cmd != "tell":
            raise ValueError(f"Teller takes ('tell', target, n, rounds), not {cmd!r}")
        ref = self.context.ref(target)
        data = payload(64)
        clock = time.perf_counter_ns
        # warm-up: a short burst, then wait for it to drain
        for _ in range(min(n, 2000)):
            ref.tell(data)
        if not ref.flush(_ASK_TIMEOUT):
            raise RuntimeError("warm-up tells were not acknowledged in time")
        calls = np.empty(n, dtype=np.int64)
        round_s = []
        for _ in range(rounds):
            start = clock()
            for i in range(n):
                t0 = clock()
                ref.tell(data)
                calls[i] = clock() - t0
            if not ref.flush(_ASK_TIMEOUT):
                raise RuntimeError(f"{n} tells were not acknowledged within {_ASK_TIMEOUT} s")
            round_s.append((clock() - start) / 1e9)
        return {"call_ns": calls, "round_s": round_s}


class TopicSink(Actor):
    """Subscribes to ``topic`` and records each message's one-way latency from its ``t`` stamp.

    Asks: ``"reset"`` clears, ``"stats"`` -> ``{"lat_ns": int64 array, "bad": count}``.
    """

    def __init__(self, topic: str, queue_size: int = 64) -> None:
        self.topic = topic
        self.queue_size = queue_size
        self.lat: list[int] = []
        self.bad = 0

    def on_start(self) -> None:
        self.context.subscribe(self.topic, self._on_message, queue_size=self.queue_size, keep="all")

    def _on_message(self, msg: dict[str, Any]) -> None:
        now = time.perf_counter_ns()  # CLOCK_MONOTONIC: one clock for every process
        self.lat.append(now - msg["t"])
        if _nbytes(msg["data"]) != msg["n"]:
            self.bad += 1

    def on_receive(self, message: Any) -> Any:
        if message == "reset":
            self.lat.clear()
            self.bad = 0
            return None
        if message == "stats":
            return {"lat_ns": np.asarray(self.lat, dtype=np.int64), "bad": self.bad}
        raise ValueError(f"TopicSink takes 'reset' or 'stats', not {message!r}")


class TopicSource(Actor):
    """Publishes stamped messages on a topic at a steady pace.

    ``("publish", topic, size, n, interval_s)`` publishes ``n`` messages
    ``{"t": perf_counter_ns, "n": size, "data": payload}`` and returns ``n``.
    """

    def on_receive(self, message: Any) -> Any:
        cmd, topic, size, n, interval = message
        if cmd != "publish":
            raise ValueError(f"TopicSource takes ('publish', topic, size, n, interval_s), not {cmd!r}")
        data = payload(size)
        clock = time.perf_counter_ns
        publish = self.context.publish
        for _ in range(n):
            publish(topic, {"t": clock(), "n": size, "data": data})
            time.sleep(interval)
        return n
