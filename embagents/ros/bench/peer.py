"""One side of the rclpy ping-pong benchmark; runs as its own process (imports rclpy).

``pong`` republishes every ``sensor_msgs/Image`` it gets on ``<prefix>/ping``
to ``<prefix>/pong`` until a message with ``frame_id == "stop"`` arrives (or
its parent dies). ``ping`` waits for discovery, warms up, then times ``n``
round trips and prints one JSON line: ``{"lat_ns": [...], "lost": k, "shm": [...]}``
(``shm``: the /dev/shm files it mapped; pong prints its own on exit).
QoS: reliable, keep last, depth 2. The bench process itself never imports
rclpy (see :mod:`embagents.bench.cases_rclpy`).

Example::

    python -m embagents.ros.bench.peer pong --prefix /b1 &
    python -m embagents.ros.bench.peer ping --prefix /b1 --size 64 --warmup 10 --n 100
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

__all__ = ["main"]


def _shm_mapped() -> list[str]:
    """What this process maps from /dev/shm (the bench checks none of it is left behind)."""
    with open("/proc/self/maps") as f:
        return sorted({line.split("/dev/shm/", 1)[1].strip() for line in f if "/dev/shm/" in line})


def main(argv: list[str] | None = None) -> int:
    """Run one side of the ping-pong; returns the exit code."""
    p = argparse.ArgumentParser(prog="python -m embagents.ros.bench.peer")
    p.add_argument("role", choices=["ping", "pong"])
    p.add_argument("--prefix", required=True)
    p.add_argument("--size", type=int, default=64)
    p.add_argument("--warmup", type=int, default=10)
    p.add_argument("--n", type=int, default=100)
    p.add_argument("--timeout", type=float, default=2.0, help="seconds before a round trip counts as lost")
    p.add_argument("--discovery", type=float, default=20.0)
    args = p.parse_args(argv)

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    qos = QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=2,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )
    parent = os.getppid()
    rclpy.init(args=[])
    node = Node(f"embagents_bench_{args.role}", start_parameter_services=False)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        if args.role == "pong":
            pub = node.create_publisher(Image, f"{args.prefix}/pong", qos)
            done = []

            def echo(msg: Image) -> None:
                if msg.header.frame_id == "stop":
                    done.append(True)
                else:
                    pub.publish(msg)

            node.create_subscription(Image, f"{args.prefix}/ping", echo, qos)
            print("READY", flush=True)
            while not done and os.getppid() == parent:
                executor.spin_once(timeout_sec=0.2)
            print(json.dumps({"shm": _shm_mapped()}), flush=True)
            return 0

        pub = node.create_publisher(Image, f"{args.prefix}/ping", qos)
        got: dict[str, int] = {}

        def on_pong(msg: Image) -> None:
            got[msg.header.frame_id] = time.perf_counter_ns()

        sub = node.create_subscription(Image, f"{args.prefix}/pong", on_pong, qos)
        deadline = time.monotonic() + args.discovery
        while pub.get_subscription_count() < 1 or sub.get_publisher_count() < 1:
            if time.monotonic() > deadline:
                print(json.dumps({"error": f"no pong peer discovered within {args.discovery} s"}), flush=True)
                return 2
            executor.spin_once(timeout_sec=0.05)
        msg = Image()
        if args.size == 1920 * 1080 * 3:
            msg.height, msg.width, msg.encoding, msg.step = 1080, 1920, "rgb8", 1920 * 3
        else:
            msg.height, msg.width, msg.encoding, msg.step = 1, args.size, "mono8", args.size
        msg.data = bytes(range(256)) * (args.size // 256) + bytes(args.size % 256)
        lat: list[int] = []
        lost = 0
        clock = time.perf_counter_ns
        for i in range(-args.warmup, args.n):
            key = str(i)
            msg.header.frame_id = key
            t0 = clock()
            pub.publish(msg)
            end = time.monotonic() + args.timeout
            while key not in got and time.monotonic() < end:
                executor.spin_once(timeout_sec=args.timeout)
            if key not in got:
                lost += i >= 0
                continue
            if i >= 0:
                lat.append(got[key] - t0)
            got.clear()
        stop = Image()
        stop.header.frame_id = "stop"
        for _ in range(3):
            pub.publish(stop)
            executor.spin_once(timeout_sec=0.05)
        print(json.dumps({"lat_ns": lat, "lost": lost, "shm": _shm_mapped()}), flush=True)
        return 0
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
