"""Policies behind a policy server: ``policy_openpi`` and ``policy_openpi_async``.

- ``policy_openpi``: the 50 Hz loop of ``vla_control_loop`` (Sim -> VLA ->
  policy -> clipped command, a chunk of 10 every 5 ticks) twice in one run:
  its ONNX policy in a local model actor, then the same policy behind
  ``embagents serve-policy`` (openpi's WebSocket protocol on loopback: the
  policy's model actor with serve-policy's options) reached by
  :class:`~embagents.models.openpi.OpenPIPolicyClient`. ``p99_jitter_ms``: of
  the command period at the Sim, over WebSocket; ``chunk_ratio``: p50 of
  observation sent -> chunk received (the VLA's ``policy_latency_ms``), over
  WebSocket / through the local model actor. Bars: <= 2 ms and <= 1.5.
- ``policy_openpi_async``: the policy served with a 100 ms inference delay, 50
  actions per chunk, at 50 Hz: the VLA with ``async_inference`` (a new chunk
  asked every 5 ticks on a worker thread, aligned to its observation's tick)
  against a synchronous ask-when-empty loop (a chunk asked when the last one
  is used up, the tick waiting for it). ``queue_empty``: ticks that found no
  action (after the first chunk), async; ``sync_queue_empty``: the same for
  the synchronous loop. Bar: async 0.
"""

from __future__ import annotations

import os
import tempfile
from typing import Any

import numpy as np

from embagents.bench.arm_parts import TARGET, jitter_ms
from embagents.bench.cases_arm import _p99, _system_file, arm_loop
from embagents.bench.registry import BenchOptions, case
from embagents.models.backends.reach_policy import write_reach_policy

__all__: list[str] = []


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _server_args(policy: str, port: int, delay_ms: float = 0.0) -> tuple[Any, ...]:
    openpi = {"bind": f"ws://127.0.0.1:{port}", "delay_ms": delay_ms}  # what serve-policy's model actor gets
    return ("policy", policy, {"threads": 1, "realtime": True, "openpi": openpi}, True)


@case("policy_openpi", transport="embagents", kind="arm", needs="websockets")
def policy_openpi(opts: BenchOptions) -> dict[str, Any]:
    seconds = 1.5 if opts.quick else 10.0
    with tempfile.TemporaryDirectory() as tmp:
        policy = write_reach_policy(os.path.join(tmp, "reach.onnx"), TARGET, gain=0.02, chunk=10)
        local, local_status = arm_loop(_system_file(tmp, "vla_system", repr(policy)), seconds,
                                    ("policy", policy, {"threads": 1, "realtime": True}, True))
        port = _free_port()
        path = _system_file(tmp, "vla_openpi_system", repr(f"ws://127.0.0.1:{port}"))
        ws, ws_status = arm_loop(path, seconds, _server_args(policy, port))
    p99, local_p99 = _p99(jitter_ms(ws, 0.02)), _p99(jitter_ms(local, 0.02))
    ws_ms, local_ms = ws_status["policy_latency_ms"], local_status["policy_latency_ms"]
    ratio = round(ws_ms / local_ms, 3) if ws_ms and local_ms else None
    ours = jitter_ms(ws, 0.02)
    return {
        "p50_us": round(float(np.median(ours)) * 1000, 2),
        "p99_us": p99 * 1000,
        "msgs_per_s": len(ws) / seconds,
        "p99_jitter_ms": p99,
        "local_p99_jitter_ms": local_p99,
        "chunk_p50_ms": ws_ms,
        "local_chunk_p50_ms": local_ms,
        "chunk_ratio": ratio,
        "server_infer_ms": round(ws_status["server_timing"].get("infer_ms", 0.0), 3),
        "commands": len(ws),
        "note": f"50 Hz, Panda 7 joints, ONNX chunk of 10 every 5 ticks, {seconds:.1f} s each: over openpi's WebSocket "
                "(serve-policy on loopback) vs a local model actor; bars: p99 jitter <= 2 ms, chunk p50 ratio <= 1.5",
    }


@case("policy_openpi_async", transport="embagents", kind="arm", needs="websockets")
def policy_openpi_async(opts: BenchOptions) -> dict[str, Any]:
    seconds = 2.0 if opts.quick else 10.0
    with tempfile.TemporaryDirectory() as tmp:
        policy = write_reach_policy(os.path.join(tmp, "reach50.onnx"), TARGET, gain=0.005, chunk=50)
        runs = {}
        for mode, rate, is_async in (("async", 10.0, True), ("sync", 1.0, False)):
            port = _free_port()
            args = f"{f'ws://127.0.0.1:{port}'!r}, chunk=50, observation_rate_hz={rate}, async_inference={is_async}, " \
                   "policy_timeout_s=0.5"
            path = _system_file(tmp, "vla_openpi_system", args)
            runs[mode] = arm_loop(path, seconds, _server_args(policy, port, delay_ms=100.0))
    (a_stamps, a_status), (s_stamps, s_status) = runs["async"], runs["sync"]
    a_jitter = jitter_ms(a_stamps, 0.02)
    return {
        "p50_us": round(float(np.median(a_jitter)) * 1000, 2),
        "p99_us": _p99(a_jitter) * 1000,
        "msgs_per_s": len(a_stamps) / seconds,
        "queue_empty": a_status["queue_empty"],
        "sync_queue_empty": s_status["queue_empty"],
        "p99_jitter_ms": _p99(a_jitter),
        "sync_p99_jitter_ms": _p99(jitter_ms(s_stamps, 0.02)),
        "chunks": a_status["chunks"],
        "sync_chunks": s_status["chunks"],
        "chunk_p50_ms": a_status["policy_latency_ms"],
        "note": f"50 Hz, 50-action chunks, 100 ms inference behind serve-policy, {seconds:.1f} s each: async refill "
                "(a chunk asked every 5 ticks on a worker thread) vs a synchronous ask-when-empty loop; "
                "bar: async queue_empty == 0",
    }
