"""``zenoh_bridge`` and ``zenoh_link_cut``: topics between two runs through their Zenoh bridges.

``zenoh_bridge``: one-way latency from a sender actor in run A (its own
process tree: :mod:`embagents.zenoh.bench_peer`) through A's bridge, Zenoh
over loopback TCP, B's bridge (in this bench process's run) to a recorder
actor in B; side by side with raw zenoh-python publisher -> subscriber
between two processes on one TCP endpoint, shared memory off. Fields
``ratio_64b`` / ``ratio_6mb`` (ours p50 / raw p50; bars <= 2.0 / <= 1.3).
Latency is one way, from the CLOCK_MONOTONIC stamp the sender writes.

``zenoh_link_cut``: a keep-all topic at 500 Hz from A to B through a TCP
forwarder that is cut for 3 s and restored, ``cuts`` times (10; 2 quick).
``lost`` (never delivered, must be 0; ``lost_reported``: what the receiving bridge
counted and logged, the same number when it is honest), ``duplicates`` (delivered twice to
the recorder, must be 0), ``resume_ms`` (restore -> first message, p50
<= 1000 ms).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from typing import Any

import numpy as np

from actors import ActorSystem
from embagents.bench.cutproxy import CutProxy
from embagents.bench.registry import FRAME_1080P, BenchOptions, case, percentiles
from embagents.zenoh.bench_peer import Recorder
from embagents.zenoh.bridge_actor import ZenohBridgeActor
from embagents.zenoh.spec import Import, ZenohBridge

__all__: list[str] = []


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _peer(*args: str) -> list[str]:
    return [sys.executable, "-m", "embagents.zenoh.bench_peer", *args]


def _chain(size: int, n: int, period: float) -> np.ndarray:
    """The floor of the bridged path's shape: 4 processes, ipc -> Zenoh -> ipc, no embagents code."""
    port = _free_port()
    with tempfile.TemporaryDirectory(prefix="eb-chain-") as tmp:
        a, b = f"{tmp}/a.sock", f"{tmp}/b.sock"
        procs: list[subprocess.Popen[str]] = []
        try:
            for args in (("chain-dst", "--path", b, "--n", str(n), "--timeout", str(n * period + 30)),
                         ("chain-hop-b", "--port", str(port), "--path", b),
                         ("chain-hop-a", "--port", str(port), "--path", a)):
                procs.append(subprocess.Popen(_peer(*args), stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True))
                assert procs[-1].stdout is not None
                if procs[-1].stdout.readline().strip() != "READY":
                    raise RuntimeError(f"bench_peer {args[0]} did not start")
            subprocess.run(_peer("chain-src", "--path", a, "--n", str(n), "--size", str(size), "--period",
                                 str(period), "--warm", "1.0"), check=True, timeout=n * period + 60)
            assert procs[0].stdout is not None
            lat = json.loads(procs[0].stdout.readline() or "[]")
        finally:
            for proc in reversed(procs):
                try:
                    proc.communicate(timeout=10)  # stdin closes: the hops return
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
    return np.asarray(lat, dtype=np.int64)


def _raw(size: int, n: int, period: float) -> np.ndarray:
    port = _free_port()
    sub = subprocess.Popen(_peer("raw-sub", "--port", str(port), "--n", str(n), "--timeout", str(n * period + 30)),
                           stdout=subprocess.PIPE, text=True)
    try:
        assert sub.stdout is not None
        sub.stdout.readline()  # READY
        subprocess.run(_peer("raw-pub", "--port", str(port), "--n", str(n), "--size", str(size), "--period",
                             str(period), "--warm", "1.0"), check=True, timeout=n * period + 60)
        lat = json.loads(sub.stdout.readline() or "[]")
    finally:
        sub.kill()
        sub.wait()
    return np.asarray(lat, dtype=np.int64)


class _RunB:
    """Run B in this process: a bridge importing ``a/bench_z`` and a recorder; run A as a process."""

    def __init__(self, port: int, connect_port: int, keep: str = "all", **send: Any) -> None:
        self.asys = ActorSystem()
        self.asys.__enter__()
        try:
            self.recorder = self.asys.spawn(Recorder, "bench_recorder", wait=60, heartbeat=None)
            bridge = ZenohBridge("b", imports=[Import("a/bench_z", topic="bench_z", keep=keep)],
                                 connect=[f"tcp/127.0.0.1:{connect_port}"], link_down_s=1.0)
            self.bridge = self.asys.spawn(ZenohBridgeActor, "_zenoh_bridge", None, bridge.to_dict(), wait=60,
                                          heartbeat=None)
            args = [f"--{k}={v}" for k, v in {**send, "keep": keep}.items()]
            self.sender = subprocess.Popen(_peer("send", "--port", str(port), *args), stdin=subprocess.PIPE,
                                           stdout=subprocess.PIPE, text=True)
            assert self.sender.stdout is not None
            self.sender.stdout.readline()  # READY
        except BaseException:
            self.close()
            raise

    def seen(self) -> list[tuple[int, int, int]]:
        return [(int(a), int(b), int(c)) for a, b, c in self.recorder.ask("seen", timeout=30).get()]

    def wait_for(self, n: int, timeout: float) -> list[tuple[int, int, int]]:
        deadline = time.monotonic() + timeout
        seen = self.seen()
        while len(seen) < n and time.monotonic() < deadline:
            time.sleep(0.2)
            seen = self.seen()
        return seen

    def counts(self) -> dict[str, int]:
        """The receiving bridge's counters (``lost``: what it reports lost; ``replayed``...)."""
        return dict(self.bridge.ask("stats", timeout=30).get()["counts"])

    def close(self) -> None:
        sender = getattr(self, "sender", None)
        if sender is not None:
            try:
                sender.communicate("\n", timeout=30)
            except subprocess.TimeoutExpired:
                sender.kill()
                sender.wait()
        self.asys.__exit__(None, None, None)


def _ours(size: int, n: int, period: float, keep: str = "all") -> np.ndarray:
    port = _free_port()
    run = _RunB(port, port, keep, n=n, size=size, period=period, warm=1.5)
    try:
        seen = run.wait_for(n, n * period + 60)
    finally:
        run.close()
    return np.asarray([lat for _, lat, _ in seen], dtype=np.int64)


@case("zenoh_bridge", transport="embagents", payload_bytes=FRAME_1080P, kind="zenoh", needs="zenoh")
def zenoh_bridge(opts: BenchOptions) -> dict[str, Any]:
    out: dict[str, Any] = {"msgs_per_s": None}
    plan = {64: (100 if opts.quick else 500, 0.01), FRAME_1080P: (10 if opts.quick else 40, 0.1)}
    for size, (n, period) in plan.items():
        skip = max(2, n // 10)  # warm-up: the first messages open the links and allocate
        raw, ours = _raw(size, n, period), _ours(size, n, period)
        if len(raw) <= skip or len(ours) <= skip:
            raise RuntimeError(f"{size} B: received raw {len(raw)}, bridged {len(ours)} of {n}")
        r, o = percentiles(raw[skip:]), percentiles(ours[skip:])
        tag = "64b" if size == 64 else "6mb"
        out.update({f"p50_us_{tag}": o["p50_us"], f"raw_p50_us_{tag}": r["p50_us"],
                    f"p99_us_{tag}": o["p99_us"], f"raw_p99_us_{tag}": r["p99_us"],
                    f"ratio_{tag}": o["p50_us"] / r["p50_us"], f"received_{tag}": len(ours)})
        if size == 64:
            # The floor of the bar's shape in the same run: what two ipc hops and two more processes cost
            # before any embagents code runs (see docs/guides/zenoh.md, "Why 64 B misses its bar").
            chain = _chain(size, n, period)
            if len(chain) <= skip:
                raise RuntimeError(f"{size} B: the bare chain received {len(chain)} of {n}")
            c = percentiles(chain[skip:])
            out.update({"chain_p50_us_64b": c["p50_us"], "chain_ratio_64b": c["p50_us"] / r["p50_us"],
                        "ours_over_chain_64b": o["p50_us"] / c["p50_us"]})
    out["p50_us"], out["p99_us"] = out["p50_us_6mb"], out["p99_us_6mb"]
    out["note"] = ("one way, component on run A -> bridge -> Zenoh TCP loopback -> bridge -> component on run B, "
                   "against raw zenoh pub -> sub processes (shm off); bars ratio_64b <= 2.0, ratio_6mb <= 1.3; "
                   "chain_ratio_64b: the same shape with no embagents code (pyzmq ipc -> zenoh -> pyzmq ipc) / raw")
    return out


@case("zenoh_link_cut", transport="embagents", payload_bytes=64, kind="zenoh", needs="zenoh")
def zenoh_link_cut(opts: BenchOptions) -> dict[str, Any]:
    cuts, cut_s, between_s, rate = (2 if opts.quick else 10), 3.0, 2.0, 500.0
    total_s = 2.0 + cuts * (cut_s + between_s) + 1.0
    n = int(total_s * rate)
    port = _free_port()
    proxy = CutProxy(port)
    restored: list[int] = []
    try:
        run = _RunB(port, proxy.port, "all", n=n, size=64, period=1.0 / rate, warm=1.5, window=5000)
        try:
            if not run.wait_for(50, 30):
                raise RuntimeError("no message reached run B before the first cut")
            time.sleep(1.0)
            for _ in range(cuts):
                proxy.cut()
                time.sleep(cut_s)
                restored.append(time.monotonic_ns())
                proxy.restore()
                time.sleep(between_s)
            seen = run.wait_for(n, 60)
            counts = run.counts()
        finally:
            run.close()
    finally:
        proxy.close()
    indices = [i for i, _, _ in seen]
    arrivals = np.asarray(sorted(t for _, _, t in seen), dtype=np.int64)
    resume = []
    for t in restored:
        k = int(np.searchsorted(arrivals, t))
        if k < len(arrivals):
            resume.append((arrivals[k] - t) / 1e6)
    lost = n - len(set(indices))
    if not resume:
        raise RuntimeError(f"nothing arrived after a restored link ({len(seen)} of {n} messages)")
    return {
        # p50_us / p99_us: restore -> first message (the table's columns); the bar reads resume_ms
        "p50_us": float(np.median(resume)) * 1e3, "p99_us": max(resume) * 1e3, "msgs_per_s": rate,
        "lost": lost, "lost_reported": counts["lost"], "duplicates": len(indices) - len(set(indices)),
        "in_order": indices == sorted(indices),
        "resume_ms": float(np.median(resume)), "resume_ms_max": max(resume),
        "cuts": cuts, "sent": n,
        "note": f"keep-all 64 B at {rate:g} Hz, {cuts} cuts of {cut_s:g} s (TCP forwarder closed and refusing); "
                "bars lost 0, duplicates 0, resume_ms p50 <= 1000",
    }
