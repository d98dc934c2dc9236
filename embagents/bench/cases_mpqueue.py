"""Baseline: ``multiprocessing.Queue`` round trips between two processes.

The payload (bytes, or a numpy array for the large sizes) is pickled into
one queue, the peer takes it and puts it into the other queue. The peer is
forked (the usual start method on Linux) after every actor system of the
run is gone.

Example::

    >>> from embagents.bench.registry import BenchOptions
    >>> ask_case(64, BenchOptions(quick=True))["p50_us"] > 0        # doctest: +SKIP
    True
"""

from __future__ import annotations

import multiprocessing as mp
import queue as _queue
import time
from typing import Any

import numpy as np

from embagents.bench.registry import BenchOptions, iterations, payload, percentiles, sized

__all__ = ["ask_case", "echo_main"]

_TIMEOUT = 30.0


def echo_main(inbox: Any, outbox: Any) -> None:
    """The peer: put back whatever arrives, until ``None``."""
    while True:
        item = inbox.get()
        if item is None:
            return
        outbox.put(item)


def ask_case(size: int, opts: BenchOptions) -> dict[str, Any]:
    """Round trips of a ``size``-byte payload through two ``multiprocessing.Queue`` objects."""
    warmup, n = iterations(size, opts)
    data = payload(size)
    ctx = mp.get_context("fork")
    inbox, outbox = ctx.Queue(), ctx.Queue()
    proc = ctx.Process(target=echo_main, args=(inbox, outbox), daemon=True)
    proc.start()
    lat = np.empty(n, dtype=np.int64)
    clock = time.perf_counter_ns
    try:
        for i in range(-warmup, n):
            t0 = clock()
            inbox.put(data)
            reply = outbox.get(timeout=_TIMEOUT)
            if i >= 0:
                lat[i] = clock() - t0
        got = reply.nbytes if isinstance(reply, np.ndarray) else len(reply)
        if got != size:
            raise RuntimeError(f"the peer answered {got} bytes, sent {size}")
        inbox.put(None)
    except _queue.Empty:
        raise RuntimeError(f"no answer from the multiprocessing peer within {_TIMEOUT} s") from None
    finally:
        proc.join(5)
        if proc.is_alive():
            proc.kill()
            proc.join()
        for q in (inbox, outbox):
            q.close()
            q.join_thread()
    res: dict[str, Any] = percentiles(lat)
    res["msgs_per_s"] = round(n / (float(lat.sum()) / 1e9), 1)
    res["samples"] = n
    res["note"] = "pickled through two multiprocessing.Queue (pipes + feeder threads)"
    return res


sized("ask", "mp_queue", ask_case)
