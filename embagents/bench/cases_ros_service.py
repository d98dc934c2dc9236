"""``ros_service``: a ``std_srvs/Trigger`` call to a component's method through the bridge, against plain rclpy.

A plain rclpy client process calls, in turn, a plain rclpy Trigger service
in its own process and the same type served by the bridge actor
(:class:`~embagents.ros.RosService`), whose request becomes a ``Call`` of an
actor's method in a third process and whose answer comes back as the
response. ``ratio``: bridge p50 / plain rclpy p50 of the round trip (bar:
<= 2.0). The calls alternate, so both see the same machine load.

Run alone: ``python -m embagents.bench --only ros_service``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from typing import Any

import embagents.requests  # noqa: F401 - registers Call, which the bridge sends the target
from actors import Actor, ActorSystem
from embagents.bench.registry import BenchOptions, case, percentiles, scoped_environ
from embagents.ros.bridge_actor import RosBridgeActor
from embagents.ros.fastdds_shm import sweeping_dead_peers

__all__ = ["TriggerTarget"]

SERVER = r"""
import sys, rclpy
from std_srvs.srv import Trigger
rclpy.init()
node = rclpy.create_node("bench_plain_trigger")
def answer(request, response):
    response.success, response.message = True, "ok"
    return response
node.create_service(Trigger, "/bench_plain_trigger", answer)
print("READY", flush=True)
try:
    rclpy.spin(node)
except Exception:
    pass
"""

# argv: warmup, n. Alternates the two services; prints {"plain": [...ns], "bridge": [...ns]}.
CLIENT = r"""
import json, sys, time, rclpy
from std_srvs.srv import Trigger
warm, n = int(sys.argv[1]), int(sys.argv[2])
rclpy.init()
node = rclpy.create_node("bench_trigger_client")
clients = {k: node.create_client(Trigger, f"/bench_{k}_trigger") for k in ("plain", "bridged")}
for c in clients.values():
    if not c.wait_for_service(timeout_sec=30):
        raise SystemExit("no service")
lat = {k: [] for k in clients}
for i in range(warm + n):
    for k, c in clients.items():
        t = time.monotonic_ns()
        f = c.call_async(Trigger.Request())
        rclpy.spin_until_future_complete(node, f, timeout_sec=10)
        dt = time.monotonic_ns() - t
        if f.result() is None or not f.result().success:
            raise SystemExit(f"{k}: no successful answer: {f.result()}")
        if i >= warm:
            lat[k].append(dt)
print(json.dumps(lat), flush=True)
"""


class TriggerTarget(Actor):
    """Answers the bridge's ``Call`` of its method at once (what a light component action costs)."""

    def on_receive(self, message: Any) -> Any:
        return "ok"


@case("ros_service", transport="embagents", payload_bytes=0, kind="ros_bridge", needs="rclpy")
def ros_service(opts: BenchOptions) -> dict[str, Any]:
    with sweeping_dead_peers():  # the rclpy peer is SIGKILLed: its Fast DDS files stay otherwise
        return _ros_service(opts)


def _ros_service(opts: BenchOptions) -> dict[str, Any]:
    warm, n = (10, 50) if opts.quick else (30, 300)
    env = {**os.environ, "ROS_DOMAIN_ID": str(150 + (os.getpid() + 31) % 80), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    server = subprocess.Popen([sys.executable, "-c", SERVER], stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert server.stdout is not None
        server.stdout.readline()
        with scoped_environ({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")}):
            with ActorSystem() as asys:
                asys.spawn(TriggerTarget, "bench_trigger_target")
                services = [{"ros_name": "/bench_bridged_trigger", "srv_type": "std_srvs/Trigger",
                             "component": "bench_trigger_target", "method": "ping"}]
                asys.spawn(RosBridgeActor, "bench_ros_bridge", None, "bench_bridge", [], [], services, wait=60)
                out = subprocess.run([sys.executable, "-c", CLIENT, str(warm), str(n)], capture_output=True, text=True,
                                     env=env, timeout=300)
    finally:
        server.kill()
        server.wait()
    if out.returncode != 0:
        raise RuntimeError(f"the rclpy client failed: {out.stderr[-800:]}")
    lat = json.loads(out.stdout.strip().splitlines()[-1])
    ours, base = percentiles(lat["bridged"]), percentiles(lat["plain"])
    return {
        **ours,
        "msgs_per_s": None,
        "rclpy_p50_us": base["p50_us"],
        "rclpy_p99_us": base["p99_us"],
        "ratio": ours["p50_us"] / base["p50_us"],
        "calls": n,
        "note": f"{n} std_srvs/Trigger calls each, alternating: via the bridge to an actor's method vs a plain "
                "rclpy service; ratio = bridge p50 / plain p50 (bar <= 2.0)",
    }
