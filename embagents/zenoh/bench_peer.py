"""Processes of the Zenoh benchmarks (``zenoh_bridge``, ``zenoh_link_cut``); each runs on its own.

- ``raw-sub`` / ``raw-pub``: plain zenoh-python publisher -> subscriber between two
  processes on one TCP endpoint, shared memory off (the baseline). The
  subscriber prints ``READY`` then one JSON line of one-way latencies (ns).
- ``chain-dst`` / ``chain-hop-b`` / ``chain-hop-a`` / ``chain-src``: the floor of
  the bridged path's shape with no embagents code in it: four processes, bytes
  through pyzmq PUSH -> PULL over ipc, a Zenoh peer -> peer hop (the bridges'
  publisher settings), and pyzmq ipc again. The hops run until their stdin
  closes; ``chain-dst`` prints ``READY`` then one JSON line of latencies (ns).
- ``send``: a run of its own (an actor system) with a Zenoh bridge exporting
  ``bench_z`` under namespace ``a`` and a sender actor publishing ``n``
  messages of ``size`` bytes, each ``{"i", "t" (CLOCK_MONOTONIC ns), "a" (uint8 array)}``,
  every ``period`` seconds after ``warm`` seconds; prints ``DONE`` when all went.

The receiving run (:class:`Recorder` behind a bridge importing ``a/bench_z``)
lives in the bench process itself (:mod:`embagents.bench.cases_zenoh`).

Example::

    python -m embagents.zenoh.bench_peer raw-sub --port 7447 --n 100 &
    python -m embagents.zenoh.bench_peer raw-pub --port 7447 --n 100 --size 64 --period 0.01
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from actors import Actor, ActorSystem
from embagents.zenoh.bridge_actor import ZenohBridgeActor
from embagents.zenoh.spec import Export, ZenohBridge

__all__ = ["Recorder", "Sender", "main"]

TOPIC = "bench_z"


def _raw_config(port: int, listen: bool) -> Any:
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints" if listen else "connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("transport/shared_memory/enabled", "false")
    return conf


def _raw_sub(port: int, n: int, timeout: float) -> None:
    import zenoh

    lat: list[int] = []
    done = threading.Event()

    def cb(sample: Any) -> None:
        data = sample.payload.to_bytes()
        lat.append(time.monotonic_ns() - int.from_bytes(data[:8], "little"))
        if len(lat) >= n:
            done.set()

    session = zenoh.open(_raw_config(port, listen=True))
    sub = session.declare_subscriber("a/bench_z", cb)
    print("READY", flush=True)
    done.wait(timeout)
    sub.undeclare()
    session.close()
    print(json.dumps(lat), flush=True)


def _chain_dst(path: str, n: int, timeout: float) -> None:
    import zmq

    with zmq.Context() as ctx, ctx.socket(zmq.PULL) as pull:
        pull.linger = 0
        pull.bind(f"ipc://{path}")
        print("READY", flush=True)
        lat: list[int] = []
        deadline = time.monotonic() + timeout
        while len(lat) < n and time.monotonic() < deadline:
            if pull.poll(int(max(0.0, deadline - time.monotonic()) * 1000)):
                data = pull.recv()
                lat.append(time.monotonic_ns() - int.from_bytes(data[:8], "little"))
    print(json.dumps(lat), flush=True)


def _until_stdin_closes(sock: Any, on_frame: Callable[[bytes], None]) -> None:
    """Hand each frame ``sock`` gets to ``on_frame`` until stdin closes (one poll on both: no busy loop)."""
    import zmq

    poller = zmq.Poller()
    poller.register(sock, zmq.POLLIN)
    poller.register(sys.stdin.fileno(), zmq.POLLIN)
    while True:
        ready = dict(poller.poll())
        if sock in ready:
            on_frame(sock.recv())
        if sys.stdin.fileno() in ready:
            return


def _chain_hop_b(port: int, path: str) -> None:
    import zenoh
    import zmq

    with zmq.Context() as ctx, ctx.socket(zmq.PUSH) as push:
        push.linger = 0
        push.connect(f"ipc://{path}")
        session = zenoh.open(_raw_config(port, listen=True))
        sub = session.declare_subscriber("a/bench_z", lambda sample: push.send(sample.payload.to_bytes()))
        print("READY", flush=True)
        sys.stdin.read()
        sub.undeclare()
        session.close()


def _chain_hop_a(port: int, path: str) -> None:
    import zenoh
    import zmq

    with zmq.Context() as ctx, ctx.socket(zmq.PULL) as pull:
        pull.linger = 0
        pull.bind(f"ipc://{path}")
        session = zenoh.open(_raw_config(port, listen=False))
        pub = session.declare_publisher("a/bench_z", congestion_control=zenoh.CongestionControl.BLOCK, express=True)
        print("READY", flush=True)
        _until_stdin_closes(pull, lambda frame: pub.put(bytearray(frame)))
        pub.undeclare()
        session.close()


def _chain_src(path: str, n: int, size: int, period: float, warm: float) -> None:
    import zmq

    body = bytearray((np.arange(max(size, 8)) % 251).astype(np.uint8).tobytes())
    with zmq.Context() as ctx, ctx.socket(zmq.PUSH) as push:
        push.linger = 1000
        push.connect(f"ipc://{path}")
        time.sleep(warm)
        for _ in range(n):
            body[:8] = time.monotonic_ns().to_bytes(8, "little")
            push.send(body)
            time.sleep(period)


def _raw_pub(port: int, n: int, size: int, period: float, warm: float) -> None:
    import zenoh

    session = zenoh.open(_raw_config(port, listen=False))
    pub = session.declare_publisher("a/bench_z", congestion_control=zenoh.CongestionControl.BLOCK, express=True)
    body = bytearray((np.arange(max(size, 8)) % 251).astype(np.uint8).tobytes())
    time.sleep(warm)
    for _ in range(n):
        body[:8] = time.monotonic_ns().to_bytes(8, "little")
        pub.put(bytearray(body))  # one copy, as the sender's write into shared memory; a bytearray is
        # zenoh's fast way in (bytes take 2.3 ms more for 6.2 MB here), and the bridge uses it too
        time.sleep(period)
    time.sleep(0.5)
    pub.undeclare()
    session.close()


class Sender(Actor):
    """Publishes ``n`` stamped messages of ``size`` bytes on ``bench_z`` every ``period`` s (on the loop's timers)."""

    def on_receive(self, message: Any) -> Any:
        n, size, period = message
        self.n, self.period, self.i = int(n), float(period), 0
        self.array = (np.arange(size) % 251).astype(np.uint8)
        self.t0 = time.monotonic()
        self.done = threading.Event()
        self._tick()
        return None

    def _tick(self) -> None:
        # Catch up with the schedule (a late timer sends what is due), then wait for the next one.
        now = time.monotonic()
        while self.i < self.n and self.t0 + self.i * self.period <= now:
            self.context.publish(TOPIC, {"i": self.i, "t": time.monotonic_ns(), "a": self.array})
            self.i += 1
        if self.i < self.n:
            self.context.call_later(max(0.0, self.t0 + self.i * self.period - time.monotonic()), self._tick)
        else:
            print("DONE", flush=True)


class Recorder(Actor):
    """Records (index, one-way latency ns, arrival CLOCK_MONOTONIC ns) of each message on ``bench_z``."""

    def on_start(self) -> None:
        self.seen: list[tuple[int, int, int]] = []
        self.context.subscribe(TOPIC, self._on, queue_size=10000, keep="all")

    def _on(self, msg: Any) -> None:
        now = time.monotonic_ns()
        self.seen.append((int(msg["i"]), now - int(msg["t"]), now))

    def on_receive(self, message: Any) -> Any:
        if message == "clear":
            self.seen = []
            return None
        return list(self.seen)


def _send(port: int, n: int, size: int, period: float, warm: float, keep: str, window: int) -> None:
    bridge = ZenohBridge("a", exports=[Export(TOPIC, keep=keep, window=window)], listen=[f"tcp/127.0.0.1:{port}"])
    with ActorSystem() as asys:
        asys.spawn(ZenohBridgeActor, "_zenoh_bridge", None, bridge.to_dict(), wait=60, heartbeat=None)
        sender = asys.spawn(Sender, "bench_sender", wait=60, heartbeat=None)
        print("READY", flush=True)
        time.sleep(warm)
        sender.ask((n, size, period), timeout=10).get()
        sys.stdin.readline()  # the bench says when it has what it needs (or closes stdin)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m embagents.zenoh.bench_peer")
    p.add_argument("role", choices=["raw-sub", "raw-pub", "chain-dst", "chain-hop-b", "chain-hop-a", "chain-src",
                                    "send"])
    p.add_argument("--port", type=int, default=0, help="the Zenoh TCP port (not for chain-dst, chain-src)")
    p.add_argument("--n", type=int, default=100)
    p.add_argument("--size", type=int, default=64)
    p.add_argument("--period", type=float, default=0.01)
    p.add_argument("--warm", type=float, default=1.0)
    p.add_argument("--timeout", type=float, default=60.0)
    p.add_argument("--keep", default="all")
    p.add_argument("--window", type=int, default=5000)
    p.add_argument("--path", default="", help="the chain's ipc socket file")
    a = p.parse_args(argv)
    if a.role == "raw-sub":
        _raw_sub(a.port, a.n, a.timeout)
    elif a.role == "raw-pub":
        _raw_pub(a.port, a.n, a.size, a.period, a.warm)
    elif a.role == "chain-dst":
        _chain_dst(a.path, a.n, a.timeout)
    elif a.role == "chain-hop-b":
        _chain_hop_b(a.port, a.path)
    elif a.role == "chain-hop-a":
        _chain_hop_a(a.port, a.path)
    elif a.role == "chain-src":
        _chain_src(a.path, a.n, a.size, a.period, a.warm)
    else:
        _send(a.port, a.n, a.size, a.period, a.warm, a.keep, a.window)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
