"""``embagents bench``: a quick real run end to end, and the case registry.

The quick run starts real actor processes, pyzmq and multiprocessing peers
and (when rclpy is installed) ROS 2 processes; it checks the JSON schema,
that every transport is there, and that nothing is left behind. It asserts
no timings: the machine running the tests is not a benchmark machine.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import uuid
from importlib.util import find_spec

import pytest

from embagents.bench.cases_gpu import cuda_available
from embagents.bench.registry import (
    CASES,
    FRAME_1080P,
    BenchOptions,
    Case,
    add,
    interleaved,
    run_case,
    run_rounds,
    select,
)
from embagents.bench.report import evaluate

# The quick run is set up inside the first test that uses it: its limit covers that (see quick_run).
pytestmark = pytest.mark.timeout(660)

SIZES = {64, 1 << 20, FRAME_1080P}
TRANSPORTS = {"embagents", "pyzmq", "mp_queue", "rclpy"}
REQUIRED = {"name": str, "transport": str, "payload_bytes": int, "p50_us": float, "p99_us": float}
HAVE_RCLPY = find_spec("rclpy") is not None


def _tagged_pids(tag: str) -> list[int]:
    """Live processes whose environment carries ``tag`` (the bench and all it started)."""
    pids = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit() or int(pid) == os.getpid():
            continue
        try:
            with open(f"/proc/{pid}/environ", "rb") as f:
                if tag.encode() in f.read():
                    pids.append(int(pid))
        except OSError:
            continue
    return pids


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, str, str]:
    out = tmp_path_factory.mktemp("bench") / "bench.json"
    tag = f"EMBAGENTS_BENCH_TEST_TAG={uuid.uuid4().hex}"
    key, value = tag.split("=")
    proc = subprocess.run(
        [sys.executable, "-m", "embagents.bench", "--quick", "--json", str(out)],
        # ~90 s on 2 quiet cores; up to 5 minutes on a loaded machine. (A quick run that once hung
        # for good now fails fast: a dead fork server or IO thread is reported, not waited on.)
        capture_output=True, text=True, timeout=600, env={**os.environ, key: value},
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return json.loads(out.read_text()), proc.stdout, tag


def test_quick_run_writes_the_documented_schema(quick_run: tuple[dict, str, str]) -> None:
    doc, _, _ = quick_run
    assert isinstance(doc["cases"], list) and doc["cases"]
    for row in doc["cases"]:
        for key, typ in REQUIRED.items():
            assert key in row, (row["name"], key)
            assert type(row[key]) is typ, (row["name"], key, row[key])
        assert "msgs_per_s" in row
        assert row["msgs_per_s"] is None or type(row["msgs_per_s"]) is float, row
        assert row["transport"] in TRANSPORTS
        assert row["p50_us"] >= 0 and row["p99_us"] >= row["p50_us"]
    names = [r["name"] for r in doc["cases"]]
    assert len(names) == len(set(names))
    assert doc["errors"] == []


def test_quick_run_covers_every_case_family(quick_run: tuple[dict, str, str]) -> None:
    doc, _, _ = quick_run
    rows = doc["cases"]
    expected = {"embagents", "pyzmq", "mp_queue"} | ({"rclpy"} if HAVE_RCLPY else set())
    assert {r["transport"] for r in rows} == expected
    for transport in expected:
        asks = {r["payload_bytes"] for r in rows if r["transport"] == transport and "ask" in r["name"]}
        assert asks == SIZES, transport
    topics = {r["payload_bytes"] for r in rows if r["transport"] == "embagents" and "topic" in r["name"]}
    assert topics == SIZES
    tell = [r for r in rows if r["transport"] == "embagents" and "tell" in r["name"]]
    assert len(tell) == 1 and tell[0]["payload_bytes"] == 64 and type(tell[0]["msgs_per_s"]) is float
    idle = [r for r in rows if r["name"] == "idle_10_actors"]
    assert len(idle) == 1 and idle[0]["transport"] == "embagents"
    assert type(idle[0]["cpu_percent"]) is float
    gpu = cuda_available()
    assert any(r["name"] == "gpu_pipeline" for r in (rows if gpu else doc["skipped"]))  # runs only on a GPU
    if not HAVE_RCLPY:
        assert {s["transport"] for s in doc["skipped"] if s["name"] != "gpu_pipeline"} == {"rclpy"}


def test_quick_run_prints_the_table_ratios_and_ungraded_bars(quick_run: tuple[dict, str, str]) -> None:
    doc, stdout, _ = quick_run
    for row in doc["cases"]:
        assert row["name"] in stdout
    assert "ours/pyzmq" in stdout
    assert "idle_10_actors" in stdout
    names = {b["name"] for b in doc["bars"]}
    assert {"ask 64B p50: ours / raw pyzmq", "tell 64B throughput", "ask 6.2MB p50", "idle 10 actors CPU"} <= names
    if HAVE_RCLPY:
        assert {"ask 64B p50: rclpy / ours", "ask 6.2MB p50: rclpy / ours"} <= names
    # A quick run is a smoke test: every bar is measured and shown, none is graded.
    for bar in doc["bars"]:
        assert bar["pass"] is None
        assert any(bar["name"] in line and "not graded" in line for line in stdout.splitlines())
    assert "PASS" not in stdout and "FAIL" not in stdout
    assert "quick run: a smoke test" in stdout
    ours = next(r for r in doc["cases"] if r["name"] == "embagents_ask_64B")
    assert type(ours["ratio_vs_pyzmq"]) is float


def test_quick_run_leaves_nothing_behind(quick_run: tuple[dict, str, str]) -> None:
    doc, _, tag = quick_run
    assert doc["shm_leftovers"] == []
    assert _tagged_pids(tag) == []


def test_only_selects_by_name_glob_transport_and_kind() -> None:
    assert [c.name for c in select(["embagents_ask_64B"])] == ["embagents_ask_64B"]
    assert {c.transport for c in select(["ask"])} == {c.transport for c in CASES.values()}
    assert all(c.transport == "pyzmq" for c in select(["pyzmq"]))
    assert {c.name for c in select(["*tell*"])} == {"embagents_tell_64B", "pyzmq_tell_64B"}
    order = [c.transport for c in select(None)]
    assert order[0] == "embagents" and order.index("pyzmq") < order.index("rclpy")
    with pytest.raises(ValueError, match="no benchmark case matches"):
        select(["no_such_case"])


def test_a_new_case_is_one_registration_and_failures_become_error_rows() -> None:
    def broken(opts: BenchOptions) -> dict:
        raise RuntimeError("boom")

    add(Case("test_broken_case", "pyzmq", 64, "demo", broken))
    try:
        with pytest.raises(ValueError, match="already registered"):
            add(Case("test_broken_case", "pyzmq", 64, "demo", broken))
        row = run_case(CASES["test_broken_case"], BenchOptions(quick=True))
        assert row["status"] == "error" and "boom" in row["error"]
        skipped = run_case(Case("x", "rclpy", 64, "ask", broken, needs="no_such_module_xyz"), BenchOptions())
        assert skipped["status"] == "skipped" and "not installed" in skipped["note"]
    finally:
        del CASES["test_broken_case"]


def test_unknown_only_name_exits_with_an_error() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "embagents.bench", "--only", "no_such_case"],
        capture_output=True, text=True, timeout=60,
    )
    assert proc.returncode == 1
    assert "no benchmark case matches" in proc.stderr


def test_interleaved_cases_run_round_robin_and_report_their_median_start() -> None:
    order: list[str] = []

    def measuring(name: str, p50s: list[float]):
        def fn(opts: BenchOptions) -> dict:
            order.append(name)
            return {"p50_us": p50s[order.count(name) - 1], "p99_us": 1.0, "msgs_per_s": None}
        return fn

    def broken(opts: BenchOptions) -> dict:
        order.append("c")
        raise RuntimeError("no peer")

    cases = [
        Case("a", "embagents", 64, "ask", measuring("a", [30.0, 10.0, 20.0])),
        Case("b", "pyzmq", 64, "ask", measuring("b", [5.0, 7.0, 6.0])),
        Case("c", "rclpy", 64, "ask", broken),
    ]
    assert all(interleaved(c) for c in cases)
    rows = run_rounds(cases, BenchOptions(), log=lambda msg: None)
    assert order == ["a", "b", "c", "a", "b", "a", "b"]  # a failing case is not tried again
    assert rows["a"]["p50_us"] == 20.0 and rows["a"]["runs_p50_us"] == [10.0, 20.0, 30.0]
    assert rows["b"]["p50_us"] == 6.0
    assert rows["c"]["status"] == "error" and "no peer" in rows["c"]["error"]


def test_a_full_run_grades_its_bars_and_a_quick_one_does_not() -> None:
    rows = [
        {"name": "embagents_ask_64B", "transport": "embagents", "kind": "ask", "payload_bytes": 64,
         "p50_us": 90.0, "p99_us": 150.0, "msgs_per_s": None},
        {"name": "pyzmq_ask_64B", "transport": "pyzmq", "kind": "ask", "payload_bytes": 64,
         "p50_us": 30.0, "p99_us": 80.0, "msgs_per_s": None},
    ]
    graded = evaluate(rows)[0]  # ask 64B p50: ours / raw pyzmq
    smoke = evaluate(rows, grade=False)[0]
    assert graded["value"] == smoke["value"] == 3.0
    assert graded["pass"] is False and smoke["pass"] is None


CHAOS_FIELDS = {
    "faults": int, "faults_by_kind": dict, "restarts": int, "lost": int, "dropped_topic": int, "duplicated": int,
    "llm_failed": int, "llm_recovered": int, "root_rss_start": int, "root_rss_end": int, "root_rss_growth": float,
    "root_fds_start": int, "root_fds_end": int, "leftover_processes": int, "leftover_shm": int,
}


@pytest.mark.skipif(find_spec("llama_cpp") is None, reason="the chaos case runs the chat system on llama.cpp")
def test_chaos_case_injects_faults_recovers_and_leaves_nothing_behind(tmp_path) -> None:
    out = tmp_path / "chaos.json"
    tag = uuid.uuid4().hex
    proc = subprocess.run(
        [sys.executable, "-m", "embagents.bench", "--only", "chaos", "--minutes", "0.1", "--json", str(out)],
        capture_output=True, text=True, timeout=300, env={**os.environ, "EMBAGENTS_BENCH_TEST_TAG": tag},
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    doc = json.loads(out.read_text())
    assert doc["errors"] == []
    (row,) = doc["cases"]
    assert row["name"] == "chaos"
    for key, typ in CHAOS_FIELDS.items():
        assert type(row[key]) is typ, (key, row.get(key))
    assert row["faults"] >= 1 and sum(row["faults_by_kind"].values()) == row["faults"]
    assert row["unrecovered_faults"] == 0 and row["restarts"] >= row["faults"]
    assert row["numbers_acked"] > 0 and row["llm_ok"] > 0 and row["frames_received"] > 0
    assert row["llm_unrecovered"] == 0 and row["llm_recovered"] <= row["llm_failed"]
    assert row["lost"] == 0, row["lost_ranges"]
    assert row["leftover_processes"] == 0 and row["leftover_shm"] == 0
    assert _tagged_pids(tag) == []
    assert "numbered messages lost" in proc.stdout and "chaos: root RSS growth" in proc.stdout


def test_quick_run_measures_the_remote_model_case_both_ways(quick_run: tuple[dict, str, str]) -> None:
    doc, _, _ = quick_run
    (row,) = [r for r in doc["cases"] if r["name"] == "remote_model"]
    assert type(row["llm_ratio"]) is float and type(row["detect_ratio"]) is float
    assert row["local_tokens_per_s"] > 0 and row["remote_tokens_per_s"] > 0
    names = {b["name"] for b in doc["bars"]}
    assert {"LLM tokens/s via TCP + CURVE / via ipc", "640x480 detection p50 via TCP + CURVE / via ipc"} <= names


@pytest.mark.skipif(find_spec("pybullet") is None or find_spec("pykka") is None, reason="the arm cases need the sim extra")
def test_quick_run_measures_the_arm_control_loop_and_gil_isolation(quick_run: tuple[dict, str, str]) -> None:
    doc, _, _ = quick_run
    rows = {r["name"]: r for r in doc["cases"]}
    vla, gil = rows["vla_control_loop"], rows["gil_isolation"]
    assert vla["commands"] > 10 and type(vla["p99_jitter_ms"]) is float and type(vla["inprocess_p99_jitter_ms"]) is float
    assert type(gil["p99_jitter_ms"]) is float and gil["threads_p99_jitter_ms"] > 0 and gil["msgs_per_s"] > 50
    assert type(gil["period_p99_jitter_ms"]) is float and type(gil["threads_period_p99_jitter_ms"]) is float
    names = {b["name"] for b in doc["bars"]}
    assert {"VLA 50 Hz command period p99 jitter", "VLA p99 jitter minus in-process",
            "100 Hz tick p99 jitter next to a GIL-heavy neighbour: processes / threads"} <= names
