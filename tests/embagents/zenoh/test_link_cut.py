"""A link cut between two runs (a TCP forwarder in between, cut and restored): keep-all loses nothing
within the replay window, counts and logs what it loses beyond it, and the bridge's health says so."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from embagents.bench.cutproxy import CutProxy
from tests.embagents.zenoh.runs import RECEIVER, SENDER, Run, free_port, wait_for, write

pytest.importorskip("zenoh")


def _linked(tmp_path: Path, window: int) -> tuple[Run, Run, CutProxy]:
    port = free_port()
    proxy = CutProxy(port)
    runs = str(tmp_path / "runs")
    a = Run(write(tmp_path, "robot_a", SENDER, f"listen=['tcp/127.0.0.1:{port}']", rate=50.0, window=window), runs)
    b = Run(write(tmp_path, "gpu_b", RECEIVER, f"connect=['tcp/127.0.0.1:{proxy.port}']", link_down_s=1.0), runs)
    try:
        wait_for(lambda: len(b.got()) >= 10, 60, "messages on run B")
    except BaseException:
        b.stop(), a.stop()
        proxy.close()
        raise
    return a, b, proxy


def test_a_three_second_cut_loses_nothing_and_sets_system_failure_meanwhile(tmp_path: Path) -> None:
    a, b, proxy = _linked(tmp_path, window=5000)
    try:
        proxy.cut()
        down = wait_for(lambda: (d := b.bridge()) and d["health"] == "SYSTEM_FAILURE" and d, 20,
                        "SYSTEM_FAILURE during the cut")
        assert down["links"][0]["state"] == "down" and "down for" in down["health_text"]
        time.sleep(max(0.0, 3.0 - 1.0))
        before = len(b.got())
        proxy.restore()
        wait_for(lambda: len(b.got()) >= before + 200, 60, "the messages sent during the cut")
        got = b.got()
        assert got == list(range(got[0], got[0] + len(got)))  # every message once, in order
        up = wait_for(lambda: (d := b.bridge()) and d["health"] == "HEALTHY" and d, 20, "HEALTHY after the cut")
        assert up["links"][0]["state"] == "up" and up["counts"]["lost"] == 0
        assert any("link tcp/127.0.0.1" in x and "down" in x for x in b.all)
        # The reports on `_health` a fallback or an event acts on: one per change of status.
        reports = [x.split()[1:] for x in b.all if x.startswith("HEALTH ")]
        assert ["_zenoh_bridge", "SYSTEM_FAILURE"] in reports and reports[-1] == ["_zenoh_bridge", "HEALTHY"]
        assert reports.count(["_zenoh_bridge", "SYSTEM_FAILURE"]) == 1
    finally:
        b.stop(), a.stop()
        proxy.close()


def test_a_cut_longer_than_the_window_counts_and_logs_the_loss(tmp_path: Path) -> None:
    a, b, proxy = _linked(tmp_path, window=5)
    try:
        proxy.cut()
        time.sleep(3.0)  # 150 messages at 50 Hz; the publisher keeps 5
        proxy.restore()
        detail = wait_for(lambda: (d := b.bridge()) and d["counts"]["lost"] > 0 and d, 60, "a counted loss")
        assert detail["counts"]["lost"] >= 100
        got = b.got()
        assert len(set(got)) == len(got) and got == sorted(got)  # what arrived: once, in order
        wait_for(lambda: any("lost: the link was down longer than the publisher's replay window" in x
                             for x in b.all), 10, "the log line of the loss")
    finally:
        b.stop(), a.stop()
        proxy.close()


def test_what_a_bridge_killed_during_a_cut_had_kept_is_counted_as_lost_on_the_other_side(tmp_path: Path) -> None:
    a, b, proxy = _linked(tmp_path, window=5000)
    try:
        proxy.cut()
        time.sleep(1.5)  # the exporting bridge keeps ~75 messages for the link to come back, then dies with them
        a.kill_bridge(1)
        proxy.restore()
        n = len(b.got())
        wait_for(lambda: len(b.got()) >= n + 50, 60, "messages after the restart")
        got = b.got()
        missing = set(range(got[0], got[-1] + 1)) - set(got)
        assert len(set(got)) == len(got) and got == sorted(got)
        detail = wait_for(lambda: (d := b.bridge()) and d["counts"]["lost"] and d, 10, "a counted loss")
        assert len(missing) >= 20 and detail["counts"]["lost"] == len(missing)  # never silent, counted exactly
        wait_for(lambda: any("the exporting bridge was killed" in x for x in b.all), 10, "the log line of the loss")
    finally:
        b.stop(), a.stop()
        proxy.close()
