"""Baseline: rclpy pub/sub ping-pong between two processes (when rclpy is installed).

Both sides run :mod:`embagents.ros.bench.peer` as subprocesses, so the
bench process never imports rclpy. Messages are ``sensor_msgs/Image``
(64 B as a 1x64 mono8 image, 1 MiB as 1x1048576 mono8, 6.2 MB as a 1080p
rgb8 frame), QoS reliable, keep last, depth 2, with the default Fast DDS
configuration. The peers report the /dev/shm files they mapped, so the
bench can check that none outlives them. Every run uses its own ``ROS_DOMAIN_ID`` (215-232, from the
pid, or ``$EMBAGENTS_BENCH_ROS_DOMAIN_ID``), localhost-only discovery and
topic names unique to the run.

Example::

    >>> from embagents.bench.registry import BenchOptions
    >>> ask_case(64, BenchOptions(quick=True))["p50_us"] > 0        # doctest: +SKIP
    True
"""

from __future__ import annotations

import contextlib
import json
import os
import select
import subprocess
import sys
import tempfile
from typing import Any

from actors import private_dir
from embagents.bench.registry import (
    FRAME_1080P,
    OWNED_SHM_NAMES,
    BenchOptions,
    iterations,
    label,
    percentiles,
    sized,
    stop_process,
)

__all__ = ["ask_case", "domain_id"]

_START_TIMEOUT = 30.0
_RUN_TIMEOUT = 90.0


def domain_id() -> int:
    """The ROS domain of this bench run.

    >>> 0 <= domain_id() <= 232
    True
    """
    env = os.environ.get("EMBAGENTS_BENCH_ROS_DOMAIN_ID")
    return int(env) if env else 215 + os.getpid() % 18


def _peer(role: str, prefix: str, *extra: str) -> tuple[subprocess.Popen, Any]:
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id()), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    err = tempfile.TemporaryFile(dir=private_dir())
    proc = subprocess.Popen(
        [sys.executable, "-m", "embagents.ros.bench.peer", role, "--prefix", prefix, *extra],
        stdout=subprocess.PIPE, stderr=err, env=env, text=True,
    )
    return proc, err


def _tail(err: Any) -> str:
    err.seek(0)
    lines = err.read().decode(errors="replace").strip().splitlines()
    return " | ".join(lines[-3:])


def _note_shm(out: str) -> None:
    """Remember the /dev/shm files a peer reported, for the leak check after the run."""
    for line in out.splitlines():
        if line.startswith("{"):
            with contextlib.suppress(ValueError):
                OWNED_SHM_NAMES.update(json.loads(line).get("shm", ()))


def ask_case(size: int, opts: BenchOptions) -> dict[str, Any]:
    """Publish a ``size``-byte Image, the pong process republishes it, time until it is back."""
    warmup, n = iterations(size, opts, "rclpy")
    prefix = f"/embagents_bench_{opts.tag}_{label(size).replace('.', '_')}"
    timeout = 3.0 if size >= FRAME_1080P else 1.0
    pong, pong_err = _peer("pong", prefix)
    ping = ping_err = None
    try:
        assert pong.stdout is not None  # _peer pipes it
        ready, _, _ = select.select([pong.stdout], [], [], _START_TIMEOUT)
        if not ready or pong.stdout.readline().strip() != "READY":
            raise RuntimeError(f"the rclpy pong process did not start: {_tail(pong_err)}")
        ping, ping_err = _peer(
            "ping", prefix, "--size", str(size), "--warmup", str(warmup), "--n", str(n), "--timeout", str(timeout)
        )
        try:
            out, _ = ping.communicate(timeout=_RUN_TIMEOUT)
        except subprocess.TimeoutExpired:
            raise RuntimeError(f"the rclpy ping-pong did not finish within {_RUN_TIMEOUT} s") from None
        lines = [line for line in out.splitlines() if line.startswith("{")]
        if ping.returncode != 0 or not lines:
            raise RuntimeError(f"the rclpy ping process failed (exit {ping.returncode}): {_tail(ping_err)}")
        result = json.loads(lines[-1])
        _note_shm(lines[-1])
        if "error" in result:
            raise RuntimeError(result["error"])
    finally:
        for proc in (ping, pong):
            if proc is not None:
                stop_process(proc)
                if proc.stdout is not None:
                    _note_shm(proc.stdout.read() if proc is pong else "")
                    proc.stdout.close()
        for f in (ping_err, pong_err):
            if f is not None:
                f.close()
    lat = result["lat_ns"]
    res: dict[str, Any] = percentiles(lat)
    res["msgs_per_s"] = round(len(lat) / (sum(lat) / 1e9), 1)
    res["samples"] = len(lat)
    res["lost"] = result["lost"]
    res["note"] = f"sensor_msgs/Image ping-pong, reliable depth 2, ROS_DOMAIN_ID={domain_id()}"
    if result["lost"]:
        res["note"] += f"; {result['lost']} of {n} lost (timed out after {timeout:g} s)"
    return res


sized("ask", "rclpy", ask_case, needs="rclpy")
