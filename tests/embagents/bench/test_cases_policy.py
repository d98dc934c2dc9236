"""``embagents bench``'s policy-server cases, quick: ``policy_openpi`` and ``policy_openpi_async`` run end to end.

Real processes: the Sim, the VLA and ``serve-policy``'s actor, openpi's
protocol on loopback. No timings are asserted (this is not a benchmark
machine); the counts that are not timings are: an async VLA loses no tick
to a 100 ms policy, a synchronous ask-when-empty loop does.
"""

from __future__ import annotations

import json
import subprocess
import sys
from importlib.util import find_spec
from pathlib import Path

import pytest

pytestmark = [pytest.mark.timeout(300),
              pytest.mark.skipif(find_spec("pybullet") is None or find_spec("websockets") is None,
                                 reason="the policy cases need the sim and vla extras")]


def test_quick_policy_cases_measure_both_sides_and_async_refill_never_runs_dry(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    proc = subprocess.run([sys.executable, "-m", "embagents.bench", "--quick", "--only", "policy_openpi*", "--json",
                           str(out)], capture_output=True, text=True, timeout=280)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    doc = json.loads(out.read_text())
    assert doc["errors"] == []
    rows = {r["name"]: r for r in doc["cases"]}
    ws = rows["policy_openpi"]
    assert ws["commands"] > 10 and type(ws["p99_jitter_ms"]) is float
    assert ws["chunk_p50_ms"] > 0 and ws["local_chunk_p50_ms"] > 0 and type(ws["chunk_ratio"]) is float
    assert ws["server_infer_ms"] > 0  # the server's own timing reached the VLA's status
    refill = rows["policy_openpi_async"]
    assert refill["queue_empty"] == 0 and refill["chunks"] > refill["sync_chunks"] > 0
    assert refill["sync_queue_empty"] >= 1  # each synchronous refill leaves the arm without an action
    names = {b["name"] for b in doc["bars"]}
    assert {"VLA 50 Hz p99 jitter, policy over openpi's WebSocket (serve-policy)",
            "VLA chunk p50 over openpi's WebSocket / through the local model actor",
            "VLA ticks without an action, 100 ms policy, async refill"} <= names
