"""``embagents bench --quick --only 'zenoh_*'``: both Zenoh cases run end to end (real runs, real links)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("zenoh")


def test_the_zenoh_cases_measure_both_paths_and_a_cut_loses_nothing(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    proc = subprocess.run([sys.executable, "-m", "embagents.bench", "--quick", "--only", "zenoh_*", "--json", str(out)],
                          capture_output=True, text=True, timeout=400)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    doc = json.loads(out.read_text())
    assert doc["errors"] == [] and doc["shm_leftovers"] == []
    rows = {r["name"]: r for r in doc["cases"]}
    bridge, cut = rows["zenoh_bridge"], rows["zenoh_link_cut"]
    for tag in ("64b", "6mb"):
        assert type(bridge[f"ratio_{tag}"]) is float and bridge[f"raw_p50_us_{tag}"] > 0
    assert bridge["received_64b"] >= 90 and bridge["received_6mb"] >= 9
    # the floor of the bar's shape (no embagents code) is measured in the same run, beside ours
    assert bridge["chain_p50_us_64b"] > 0 and bridge["chain_ratio_64b"] == bridge["chain_p50_us_64b"] / bridge["raw_p50_us_64b"]
    assert bridge["ours_over_chain_64b"] == bridge["p50_us_64b"] / bridge["chain_p50_us_64b"]
    assert cut["lost"] == 0 and cut["lost_reported"] == 0 and cut["duplicates"] == 0 and cut["in_order"] is True and cut["cuts"] == 2
    assert 0 < cut["resume_ms"] < 5000
    names = {b["name"] for b in doc["bars"]}
    assert {"Zenoh bridges run A -> run B, 64 B p50 / raw zenoh", "keep-all 500 Hz across 3 s link cuts: lost",
            "link back -> first message p50"} <= names
