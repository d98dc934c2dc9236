"""Cases on our runtime: ask round trips, topic one-way latency, pipelined tells.

Each case starts its own :class:`~actors.ActorSystem` with two actor
processes (see :mod:`embagents.bench.workers`), lets the measuring actor
run its loop, collects the numbers with one ask and shuts everything down.

Example::

    >>> from embagents.bench.registry import BenchOptions
    >>> row = ask_case(64, BenchOptions(quick=True))                  # doctest: +SKIP
    >>> sorted(row)                                                   # doctest: +SKIP
    ['msgs_per_s', 'note', 'p50_us', 'p99_us', 'samples']
"""

from __future__ import annotations

import contextlib
import logging
import math
import time
from collections.abc import Iterator
from typing import Any

import numpy as np

from actors import ActorSystem
from actors.runtime import shm_prefix
from embagents.bench.registry import (
    OWNED_SHM_PREFIXES,
    BenchOptions,
    Case,
    add,
    iterations,
    percentiles,
    sized,
)
from embagents.bench.workers import Counter, Echo, Pinger, Teller, TopicSink, TopicSource

__all__ = ["actor_system", "ask_case", "tell_case", "topic_case"]

_COLLECT_TIMEOUT = 120.0
# Pause between two topic messages: one-way latency, not queueing, is measured.
_TOPIC_INTERVAL = {64: 0.0005, 1 << 20: 0.002}
_TOPIC_INTERVAL_LARGE = 0.01
# The publisher's shared-memory ring reuses a segment only after 0.5 s:
# warm up at least that long so the measured frames see the steady state.
_TOPIC_WARMUP_S = 0.6


@contextlib.contextmanager
def actor_system() -> Iterator[ActorSystem]:
    """A fresh ActorSystem for one case, always shut down (processes, sockets, /dev/shm).

    >>> with actor_system() as system:                                # doctest: +SKIP
    ...     system.spawn(Echo, "echo")
    """
    system = ActorSystem(log_level=logging.WARNING)
    OWNED_SHM_PREFIXES.add(shm_prefix(system.run_id))
    try:
        yield system
    finally:
        system.shutdown()


def ask_case(size: int, opts: BenchOptions) -> dict[str, Any]:
    """A Pinger actor process asks an Echo actor process ``n`` times with a ``size``-byte payload."""
    warmup, n = iterations(size, opts)
    with actor_system() as system:
        system.spawn(Echo, "echo")
        pinger = system.spawn(Pinger, "pinger")
        lat = pinger.ask(("ask", "echo", size, warmup, n), timeout=_COLLECT_TIMEOUT).get()
    res: dict[str, Any] = percentiles(lat)
    res["msgs_per_s"] = round(n / (float(np.sum(lat)) / 1e9), 1)
    res["samples"] = n
    res["note"] = "ask from inside an actor handler; msgs/s = round trips/s, one in flight"
    return res


def topic_case(size: int, opts: BenchOptions) -> dict[str, Any]:
    """A TopicSource actor publishes stamped messages; a TopicSink actor in another process measures one-way latency."""
    warmup, n = iterations(size, opts, "topic")
    interval = _TOPIC_INTERVAL.get(size, _TOPIC_INTERVAL_LARGE)
    topic = "bench.frames"
    with actor_system() as system:
        sink = system.spawn(TopicSink, "sink", topic, 64)
        source = system.spawn(TopicSource, "source")
        # Publish until the subscriber is connected (PUB/SUB drops while joining).
        deadline = time.monotonic() + 10
        while len(sink.ask("stats", timeout=10).get()["lat_ns"]) == 0:
            if time.monotonic() > deadline:
                raise RuntimeError("the subscriber received nothing within 10 s")
            source.ask(("publish", topic, size, 5, interval), timeout=30).get()
        warm = max(warmup, math.ceil(_TOPIC_WARMUP_S / interval)) if size >= 64 * 1024 else warmup
        source.ask(("publish", topic, size, warm, interval), timeout=_COLLECT_TIMEOUT).get()
        time.sleep(0.05)
        sink.ask("reset", timeout=10).get()
        source.ask(("publish", topic, size, n, interval), timeout=_COLLECT_TIMEOUT).get()
        deadline = time.monotonic() + 3
        while True:
            stats = sink.ask("stats", timeout=10).get()
            if len(stats["lat_ns"]) >= n or time.monotonic() > deadline:
                break
            time.sleep(0.02)
    lat = stats["lat_ns"]
    res: dict[str, Any] = percentiles(lat)
    res["msgs_per_s"] = None
    res["samples"] = len(lat)
    lost = n - len(lat)
    res["note"] = f"one-way, publish every {interval * 1000:g} ms" + (f"; {lost} of {n} lost" if lost else "")
    if stats["bad"]:
        res["note"] += f"; {stats['bad']} with a wrong size"
    return res


def tell_case(opts: BenchOptions) -> dict[str, Any]:
    """A Teller actor tells ``n`` 64-byte messages to a Counter actor, then flushes (waits for every ack)."""
    n, rounds = (5000, 2) if opts.quick else (50000, 3)
    with actor_system() as system:
        counter = system.spawn(Counter, "counter")
        teller = system.spawn(Teller, "teller")
        out = teller.ask(("tell", "counter", n, rounds), timeout=_COLLECT_TIMEOUT).get()
        handled = counter.ask("count", timeout=10).get()
    expected = n * rounds + min(n, 2000)
    if handled != expected:
        raise RuntimeError(f"the counter handled {handled} messages, {expected} were told")
    res: dict[str, Any] = percentiles(out["call_ns"])
    res["msgs_per_s"] = round(n / float(np.median(out["round_s"])), 1)
    res["samples"] = n * rounds
    res["note"] = f"{n} tells then flush, median of {rounds}; p50/p99 = sender cost of one tell()"
    return res


sized("ask", "embagents", ask_case)
sized("topic", "embagents", topic_case)
add(Case("embagents_tell_64B", "embagents", 64, "tell", tell_case))
