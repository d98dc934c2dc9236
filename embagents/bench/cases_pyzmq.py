"""Baseline: raw pyzmq over ipc between two processes, no serialization, no guarantees.

* ``pyzmq_ask_*``: a DEALER sends the payload, a ROUTER in another process
  sends it straight back (zero-copy sends of numpy buffers; the kernel
  copies through the unix socket).
* ``pyzmq_topic_*``: PUB -> SUB one-way latency, the stamp in a first frame.
* ``pyzmq_tell_64B``: a DEALER sends ``n`` 64-byte frames, then a marker the
  peer answers once it has read everything.

The peer is a fresh interpreter (``python -c``): no inherited sockets or
threads, and no re-import of the caller's ``__main__``.

Example::

    >>> from embagents.bench.registry import BenchOptions
    >>> ask_case(64, BenchOptions(quick=True))["p50_us"] > 0        # doctest: +SKIP
    True
"""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from typing import Any, cast

import numpy as np
import zmq

from actors import private_dir
from embagents.bench.registry import (
    BenchOptions,
    Case,
    add,
    iterations,
    payload,
    percentiles,
    sized,
    stop_process,
)

__all__ = ["ask_case", "peer_main", "tell_case", "topic_case"]

_TIMEOUT_MS = 30_000
_STAMP = struct.Struct("<q")
_TOPIC_INTERVAL = {64: 0.0005, 1 << 20: 0.002}
_TOPIC_INTERVAL_LARGE = 0.01
_PEER = "import sys; from embagents.bench.cases_pyzmq import peer_main; peer_main(*sys.argv[1:])"


def peer_main(mode: str, endpoint: str, extra: str) -> None:
    """The other process: ``echo`` (ROUTER), ``sub`` (SUB + results back on ``extra``) or ``sink`` (counts tells)."""
    ctx = zmq.Context()
    try:
        if mode == "echo":
            s = ctx.socket(zmq.ROUTER)
            s.bind(endpoint)
            while True:
                parts = s.recv_multipart(copy=False)
                if len(parts[1]) == 4 and parts[1].bytes == b"stop":
                    break
                s.send_multipart(parts, copy=False)
        elif mode == "sink":
            s = ctx.socket(zmq.ROUTER)
            s.rcvhwm = 0
            s.bind(endpoint)
            n = 0
            while True:
                ident = s.recv()
                body = s.recv()  # two recv() calls: recv_multipart() costs ~5 us more
                if body == b"done":
                    s.send_multipart([ident, str(n).encode()])
                    n = 0
                elif body == b"stop":
                    break
                else:
                    n += 1
        elif mode == "sub":
            s = ctx.socket(zmq.SUB)
            s.setsockopt(zmq.SUBSCRIBE, b"")
            s.rcvhwm = 0
            s.bind(endpoint)
            back = ctx.socket(zmq.PAIR)
            back.connect(extra)
            poller = zmq.Poller()
            poller.register(s, zmq.POLLIN)
            poller.register(back, zmq.POLLIN)
            lat: list[int] = []
            while True:
                for sock, _ in poller.poll():
                    if sock is s:
                        stamp, data = s.recv_multipart(copy=False)
                        now = time.perf_counter_ns()
                        lat.append(now - _STAMP.unpack(stamp.bytes)[0])
                        del data
                    else:
                        cmd = back.recv()
                        if cmd == b"stats":
                            back.send(np.asarray(lat, dtype=np.int64).tobytes())
                        elif cmd == b"reset":
                            lat.clear()
                            back.send(b"ok")
                        else:
                            return
        else:
            raise ValueError(f"unknown peer mode {mode!r}")
    finally:
        ctx.destroy(linger=0)


@contextlib.contextmanager
def peer(mode: str, extra: str = "") -> Iterator[tuple[zmq.Context, str]]:
    """Start the peer process; yield (a context, the ipc endpoint); always stop it."""
    d = tempfile.mkdtemp(prefix="eabench-", dir=private_dir())  # 0700, unpredictable
    endpoint = f"ipc://{d}/peer"
    if extra == "back":
        extra = f"ipc://{d}/back"
    proc = subprocess.Popen([sys.executable, "-c", _PEER, mode, endpoint, extra])
    ctx = zmq.Context()
    try:
        deadline = time.monotonic() + 30
        while not os.path.exists(f"{d}/peer"):
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"the pyzmq {mode} peer did not start (exit code {proc.poll()})")
            time.sleep(0.005)
        yield ctx, endpoint
    finally:
        ctx.destroy(linger=0)
        stop_process(proc)
        shutil.rmtree(d, ignore_errors=True)


def _sendable(size: int) -> bytes | memoryview:
    """``payload(size)`` as pyzmq's types take it: an array as its memoryview (the same buffer, no copy)."""
    data = payload(size)
    return data if isinstance(data, bytes) else data.data


def _socket(ctx: zmq.Context, kind: int, endpoint: str) -> zmq.Socket:
    s = ctx.socket(kind)
    s.linger = 0
    s.rcvtimeo = _TIMEOUT_MS
    s.sndtimeo = _TIMEOUT_MS
    s.connect(endpoint)
    return s


def ask_case(size: int, opts: BenchOptions) -> dict[str, Any]:
    """DEALER -> ROUTER echo -> DEALER round trips of ``size`` bytes."""
    warmup, n = iterations(size, opts)
    data = _sendable(size)
    with peer("echo") as (ctx, endpoint):
        s = _socket(ctx, zmq.DEALER, endpoint)
        clock = time.perf_counter_ns
        lat = np.empty(n, dtype=np.int64)
        for i in range(-warmup, n):
            t0 = clock()
            s.send(data, 0, copy=size < 65536)  # flags given: the stubs take a bool copy only then
            reply = s.recv(copy=size < 65536)
            if size >= 65536:
                arr = np.frombuffer(cast(zmq.Frame, reply).buffer, dtype=np.uint8)  # what a user would do (copy=False: a Frame)
                del arr
            if i >= 0:
                lat[i] = clock() - t0
        got = len(reply) if isinstance(reply, bytes) else len(reply.buffer)
        if got != size:
            raise RuntimeError(f"the echo answered {got} bytes, sent {size}")
        s.send(b"stop")
        s.close()
    res: dict[str, Any] = percentiles(lat)
    res["msgs_per_s"] = round(n / (float(lat.sum()) / 1e9), 1)
    res["samples"] = n
    res["note"] = "raw bytes, zero-copy send/recv, no serialization"
    return res


def topic_case(size: int, opts: BenchOptions) -> dict[str, Any]:
    """PUB -> SUB one-way latency at the same pace as ``embagents_topic_*``."""
    warmup, n = iterations(size, opts, "topic")
    interval = _TOPIC_INTERVAL.get(size, _TOPIC_INTERVAL_LARGE)
    data = _sendable(size)
    clock = time.perf_counter_ns
    with peer("sub", "back") as (ctx, endpoint):
        back_ep = endpoint[: -len("peer")] + "back"
        back = ctx.socket(zmq.PAIR)
        back.linger = 0
        back.rcvtimeo = _TIMEOUT_MS
        back.bind(back_ep)
        pub = _socket(ctx, zmq.PUB, endpoint)
        pub.sndhwm = 0

        def stats() -> np.ndarray:
            back.send(b"stats")
            return np.frombuffer(back.recv(), dtype=np.int64)

        def publish(count: int) -> None:
            for _ in range(count):
                pub.send_multipart([_STAMP.pack(clock()), data], copy=size < 65536)
                time.sleep(interval)

        deadline = time.monotonic() + 10
        while len(stats()) == 0:
            if time.monotonic() > deadline:
                raise RuntimeError("the SUB peer received nothing within 10 s")
            publish(5)
        publish(max(warmup, math.ceil(0.2 / interval)))
        time.sleep(0.05)
        back.send(b"reset")
        back.recv()
        publish(n)
        deadline = time.monotonic() + 3
        while len(lat := stats()) < n and time.monotonic() < deadline:
            time.sleep(0.02)
        back.send(b"stop")
        pub.close()
        back.close()
    res: dict[str, Any] = percentiles(lat)
    res["msgs_per_s"] = None
    res["samples"] = len(lat)
    lost = n - len(lat)
    res["note"] = f"one-way, publish every {interval * 1000:g} ms" + (f"; {lost} of {n} lost" if lost else "")
    return res


def tell_case(opts: BenchOptions) -> dict[str, Any]:
    """``n`` 64-byte DEALER sends as fast as possible, then a marker the peer answers."""
    n, rounds = (5000, 2) if opts.quick else (50000, 3)
    data = _sendable(64)
    clock = time.perf_counter_ns
    with peer("sink") as (ctx, endpoint):
        s = _socket(ctx, zmq.DEALER, endpoint)
        s.sndhwm = 0
        for _ in range(min(n, 2000)):
            s.send(data)
        s.send(b"done")
        s.recv()
        calls = np.empty(n, dtype=np.int64)
        round_s = []
        for _ in range(rounds):
            start = clock()
            for i in range(n):
                t0 = clock()
                s.send(data)
                calls[i] = clock() - t0
            s.send(b"done")
            got = int(s.recv())
            round_s.append((clock() - start) / 1e9)
            if got != n:
                raise RuntimeError(f"the sink counted {got} messages, {n} were sent")
        s.send(b"stop")
        s.close()
    res: dict[str, Any] = percentiles(calls)
    res["msgs_per_s"] = round(n / float(np.median(round_s)), 1)
    res["samples"] = n * rounds
    res["note"] = f"{n} sends then a marker, median of {rounds}; no acks, no retries"
    return res


sized("ask", "pyzmq", ask_case)
sized("topic", "pyzmq", topic_case)
add(Case("pyzmq_tell_64B", "pyzmq", 64, "tell", tell_case))
