"""``ros_bridge_recovery``: SIGKILL the ROS bridge mid-stream; how long until the flow is back.

A plain rclpy node streams /ping at 20 Hz and records when each /pong comes
back. The system under test echoes /ping to /pong through the bridge actor
of ``embagents supervise`` (RosInput -> internal topic -> RosOutput). The
bench SIGKILLs the bridge ``n`` times; one outage is the time from the kill
to the first /pong after it. In the same run the same streamer is served by
a plain rclpy echo node that the bench respawns at once after each SIGKILL
(what a launch file's ``respawn=True`` does at best): ``ratio`` is bridge
p50 / respawned-node p50. Bar: the bridge's worst outage <= 2 s.
"""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from actors import private_dir
from embagents.bench.registry import BenchOptions, case, stop_process
from embagents.ros.fastdds_shm import sweeping_dead_peers

__all__ = ["ECHO_SYSTEM", "bridge_pid"]

ECHO_SYSTEM = """
from embagents import System
from embagents.ros import RosInput, RosOutput

# The bench kills the bridge every ~1.5 s: allow that many restarts (the default is 3 in 5 s).
system = System([], ros=[RosInput("/ping", "std_msgs/String", topic="ping"),
                         RosOutput("ping", ros_topic="/pong", ros_type="std_msgs/String")],
                supervision={"intensity": 100, "period": 60.0})
"""

PEER = [sys.executable, "-m", "embagents.ros.bench.recovery_peer"]  # streamer / echo: plain rclpy processes

_SETTLE = 1.0  # s of steady flow before each kill
_IN_FLIGHT = 0.15  # s: a /pong this soon after a kill was sent before it
_GIVE_UP = 30.0  # s without a /pong after a kill: the flow is not coming back


def _outages(env: dict[str, str], n: int, kill: Callable[[], float]) -> list[float]:
    """Start the streamer, ``kill()`` the echo side ``n`` times, return each outage (s).

    ``kill`` returns the monotonic time of its SIGKILL.
    """
    streamer = subprocess.Popen([*PEER, "streamer"], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                env=env)
    arrivals: queue.Queue[float] = queue.Queue()
    assert streamer.stdout is not None and streamer.stdin is not None

    def read() -> None:
        for x in streamer.stdout or ():
            arrivals.put(float(x))

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    out = []
    try:
        _next_after(arrivals, 0.0)  # flowing
        for _ in range(n):
            time.sleep(_SETTLE)
            k = kill()
            out.append(_next_after(arrivals, k + _IN_FLIGHT) - k)
    finally:
        streamer.stdin.close()
        stop_process(streamer)
        reader.join(5)
    return out


def _next_after(arrivals: queue.Queue[float], t: float) -> float:
    deadline = time.monotonic() + _GIVE_UP
    while True:
        try:
            a = arrivals.get(timeout=max(0.0, deadline - time.monotonic()))
        except queue.Empty:
            raise RuntimeError(f"no /pong for {_GIVE_UP:.0f} s: the /ping -> /pong echo is not answering") from None
        if a > t:
            return a


def _kill(pid: int) -> float:
    t = time.monotonic()
    os.kill(pid, signal.SIGKILL)
    return t


def bridge_pid(sup: subprocess.Popen, env: dict[str, str] | None = None) -> int:
    """The pid of the ROS bridge of the ``embagents supervise`` process ``sup`` (asks ``embagents status``)."""
    st = subprocess.run([sys.executable, "-m", "embagents.cli", "status", "--json", "--run", str(sup.pid)],
                        capture_output=True, text=True, timeout=30, env=env)
    if st.returncode != 0:
        raise RuntimeError(f"embagents status failed: {st.stderr.strip()[-500:]}")
    return next(r["pid"] for r in json.loads(st.stdout)["rows"] if r["name"] == "_ros_bridge")


def _supervised(env: dict[str, str], n: int) -> list[float]:
    with tempfile.TemporaryDirectory(prefix="embagents-bench-", dir=private_dir()) as d:
        path = os.path.join(d, "system.py")
        with open(path, "w") as f:
            f.write(ECHO_SYSTEM)
        log = open(os.path.join(d, "supervise.log"), "w+")  # noqa: SIM115 - closed below
        sup = subprocess.Popen([sys.executable, "-m", "embagents.cli", "supervise", path],
                               stdout=log, stderr=subprocess.STDOUT, env=env)
        try:
            return _outages(env, n, lambda: _kill(bridge_pid(sup, env)))
        except RuntimeError as exc:
            log.seek(0)
            raise RuntimeError(f"{exc}; embagents supervise said: {log.read()[-1500:]}") from None
        finally:
            sup.send_signal(signal.SIGTERM)
            stop_process(sup, grace=30)
            log.close()


def _respawned(env: dict[str, str], n: int) -> list[float]:
    procs = [subprocess.Popen([*PEER, "echo"], env=env)]

    def kill_and_respawn() -> float:
        k = _kill(procs[-1].pid)
        procs[-1].wait()
        procs.append(subprocess.Popen([*PEER, "echo"], env=env))
        return k

    try:
        return _outages(env, n, kill_and_respawn)
    finally:
        for p in procs:
            stop_process(p, grace=0)


@case("ros_bridge_recovery", transport="embagents", kind="ros_bridge", needs="rclpy")
def ros_bridge_recovery(opts: BenchOptions) -> dict[str, Any]:
    n = 2 if opts.quick else 12
    env = {**os.environ, "ROS_DOMAIN_ID": str(100 + os.getpid() % 40), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    with sweeping_dead_peers():  # the processes this case SIGKILLs cannot unlink their Fast DDS files
        ours = np.asarray(_supervised(env, n)) * 1e6
        base = np.asarray(_respawned(env, n)) * 1e6
    p50, p99 = np.percentile(ours, [50, 99])
    b50 = float(np.percentile(base, 50))
    return {
        "p50_us": round(float(p50), 1),
        "p99_us": round(float(p99), 1),
        "max_us": round(float(ours.max()), 1),
        "msgs_per_s": None,
        "samples": n,
        "outages_s": [round(x / 1e6, 3) for x in ours],
        "respawn_outages_s": [round(x / 1e6, 3) for x in base],
        "respawn_p50_us": round(b50, 1),
        "respawn_max_us": round(float(base.max()), 1),
        "ratio": float(p50) / b50,
        "note": f"{n} SIGKILLs of the bridge, 20 Hz /ping -> /pong; ratio = bridge p50 / respawned rclpy node p50; "
        "bar: max <= 2 s",
    }
