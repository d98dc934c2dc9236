"""The plain rclpy nodes of the ``ros_bridge_recovery`` benchmark; each runs as its own process.

``streamer`` publishes ``std_msgs/String`` on /ping every 50 ms and prints
the CLOCK_MONOTONIC time of each /pong it receives, one per line, until its
stdin closes. ``echo`` republishes every /ping on /pong: the plain-ROS
stand-in for the bridge, which the bench respawns after each SIGKILL. The
bench process itself never imports rclpy (see
:mod:`embagents.bench.cases_ros_recovery`).

Example::

    python -m embagents.ros.bench.recovery_peer echo &
    python -m embagents.ros.bench.recovery_peer streamer    # prints /pong arrival times
"""

from __future__ import annotations

import argparse
import select
import sys
import time

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    """Run the ``streamer`` or the ``echo`` node; returns the exit code."""
    p = argparse.ArgumentParser(prog="python -m embagents.ros.bench.recovery_peer")
    p.add_argument("role", choices=["streamer", "echo"])
    args = p.parse_args(argv)

    import rclpy
    from std_msgs.msg import String

    rclpy.init(args=[])
    node = rclpy.create_node(f"recovery_{args.role}")
    try:
        if args.role == "echo":
            pub = node.create_publisher(String, "/pong", 10)
            node.create_subscription(String, "/ping", pub.publish, 10)
            rclpy.spin(node)
            return 0
        pub = node.create_publisher(String, "/ping", 10)
        node.create_subscription(String, "/pong", lambda _: print(time.monotonic(), flush=True), 10)
        i = 0
        while not select.select([sys.stdin], [], [], 0)[0]:
            pub.publish(String(data=str(i)))
            i += 1
            end = time.monotonic() + 0.05
            while time.monotonic() < end:
                rclpy.spin_once(node, timeout_sec=0.01)
        return 0
    except KeyboardInterrupt:
        return 0
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
