"""``gpu_pipeline``: a CUDA model in a component actor, measured where a GPU is (skipped elsewhere).

What runs: ``examples/gpu_pipeline.py`` under ``embagents supervise``: 1080p
frames at 30 Hz through ResNet-50 (fp16) in a spawned component with a warm
standby; at half the frames the component poisons its CUDA context (a
device-side assert), its fallback restarts it, and the standby takes over.
The same run without the standby, and the same frames through the same
network in one process (``python examples/gpu_pipeline.py``), are measured
beside it. Each run is its own process: CUDA never enters the bench's
process, whose later cases fork.

Reported: the card (``device``), frame latency p50/p99 through the runtime
and in-process (``ratio``), ``recovery_s`` from the poisoning to the first
result of the new process with and without the standby, the longest gap
between results and the frames missing. Without ``torch.cuda.is_available()``
the case is skipped; CI runs the same pipeline on its numpy stand-in
(:func:`run_pipeline`, ``tests/embagents/bench/test_cases_gpu.py``). How to run it
and the numbers of GPU runs: ``docs/guides/gpu.md``.

Example::

    >>> run_pipeline(60, 30, standby=True)["recovery_s"] is not None     # doctest: +SKIP
    True
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from embagents.bench.registry import BenchOptions, Skipped, case

__all__ = ["EXAMPLE", "cuda_available", "run_in_process", "run_pipeline"]

#: The system file the case runs (in a source checkout).
EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "gpu_pipeline.py"


def cuda_available() -> bool:
    """``torch.cuda.is_available()``, asked in a child process (CUDA stays out of this one)."""
    code = "import torch, sys; sys.exit(0 if torch.cuda.is_available() else 1)"
    try:
        return subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=120).returncode == 0
    except subprocess.TimeoutExpired:
        return False


def _env(frames: int, poison_at: int, out: str, standby: bool) -> dict[str, str]:
    return {**os.environ, "GPU_FRAMES": str(frames), "GPU_POISON_AT": str(poison_at), "GPU_OUT": out,
            "GPU_STANDBY": "1" if standby else "0"}


def run_pipeline(frames: int, poison_at: int, *, standby: bool, timeout: float = 600) -> dict[str, Any]:
    """One ``embagents supervise examples/gpu_pipeline.py`` run; its ``pipeline.json`` (see the example)."""
    with tempfile.TemporaryDirectory(prefix="gpu-bench-") as out:
        proc = subprocess.run([sys.executable, "-m", "embagents.cli", "supervise", str(EXAMPLE)],
                              env=_env(frames, poison_at, out, standby), capture_output=True, text=True,
                              timeout=timeout)
        path = os.path.join(out, "pipeline.json")
        if not os.path.exists(path):
            raise RuntimeError(f"the pipeline wrote no result (exit {proc.returncode}):\n{proc.stderr[-3000:]}")
        with open(path) as f:
            return json.load(f)


def run_in_process(frames: int, timeout: float = 600) -> dict[str, Any]:
    """The same frames through the same network in one process (``python examples/gpu_pipeline.py``)."""
    with tempfile.TemporaryDirectory(prefix="gpu-bench-") as out:
        proc = subprocess.run([sys.executable, str(EXAMPLE)], env=_env(frames, frames + 1, out, False),
                              capture_output=True, text=True, timeout=timeout)
    line = next((x for x in proc.stdout.splitlines() if x.startswith("INPROC ")), None)
    if line is None:
        raise RuntimeError(f"the in-process run printed no result (exit {proc.returncode}):\n{proc.stderr[-3000:]}")
    return json.loads(line[len("INPROC "):])


@case("gpu_pipeline", transport="embagents", kind="gpu")
def gpu_pipeline(opts: BenchOptions) -> dict[str, Any]:
    if not EXAMPLE.exists():
        raise Skipped(f"{EXAMPLE} is not here: run the bench from a source checkout")
    if not cuda_available():
        raise Skipped("no CUDA here (torch.cuda.is_available() is not True); CI runs the CPU path of the same code")
    frames = 300 if opts.quick else 600
    inproc = run_in_process(frames)
    warm = run_pipeline(frames, frames // 2, standby=True)
    cold = run_pipeline(frames, frames // 2, standby=False)
    return {
        "p50_us": round(warm["latency_p50_ms"] * 1000, 1), "p99_us": round(warm["latency_p99_ms"] * 1000, 1),
        "msgs_per_s": None, "device": warm["device"],
        "inproc_p50_ms": round(inproc["latency_p50_ms"], 2), "inproc_p99_ms": round(inproc["latency_p99_ms"], 2),
        "ratio": round(warm["latency_p50_ms"] / inproc["latency_p50_ms"], 3),
        "model_ready_s": round(inproc["ready_s"], 2),
        "recovery_s": warm["recovery_s"], "recovery_s_no_standby": cold["recovery_s"],
        "max_gap_ms": round(warm["max_gap_ms"], 1), "max_gap_ms_no_standby": round(cold["max_gap_ms"], 1),
        "frames_missing": warm["frames_missing"], "frames_missing_no_standby": cold["frames_missing"],
        "note": f"1080p at 30 Hz through ResNet-50 fp16 on {warm['device']}; CUDA context poisoned at frame "
                f"{frames // 2}; recovered by a warm standby (recovery_s) or a fresh spawn (recovery_s_no_standby)",
    }
