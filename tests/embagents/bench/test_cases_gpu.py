"""The GPU bench case's pipeline on its CPU path (CI has no GPU): the same code, a numpy stand-in."""

from __future__ import annotations

import pytest

from embagents.bench.cases_gpu import EXAMPLE, cuda_available, run_in_process, run_pipeline
from embagents.bench.registry import CASES, BenchOptions, run_case


def test_the_pipeline_recovers_from_a_poisoned_model_through_its_standby_on_the_cpu_path() -> None:
    res = run_pipeline(90, 45, standby=True, timeout=300)
    assert res["device"] == "cpu (numpy stand-in)" and res["standby"] is True
    assert len(res["pids"]) == 2, res  # the poisoned process, then the standby that took over
    # Frames are keep-latest sensor data: a few are lost to the fault, most are not.
    assert res["recovery_s"] is not None and res["frames_missing"] < 45 and res["results"] >= 45, res


def test_the_in_process_baseline_runs_the_same_network() -> None:
    res = run_in_process(40, timeout=120)
    assert res["cuda"] is False and res["latency_p50_ms"] >= 0


def test_without_cuda_the_bench_case_is_skipped_saying_why() -> None:
    if cuda_available():
        pytest.skip("a GPU is here: the case runs")
    row = run_case(CASES["gpu_pipeline"], BenchOptions(quick=True))
    assert row["status"] == "skipped" and "no CUDA here" in row["note"]
    assert EXAMPLE.exists()
