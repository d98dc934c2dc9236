"""The ``chaos`` case's numbered streams and their tally, under the real supervisor (no LLM).

The whole case runs in test_run.py; faults there are drawn at random. Here one
fault is injected on purpose, so what it does to the counts is checked every time.
"""

from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import Any

from actors import ActorSystem
from embagents.bench.cases_chaos import HEARTBEAT, _Watch
from embagents.bench.chaos_tally import read_records, tally_numbers, watermark
from embagents.bench.chaos_workers import SINK, NumberSink, NumberSource
from supervisor import ChildSpec, SupervisorSpec, Tree, start_supervisor
from tests.helpers import wait_until

SOURCE = "chaos_source"


def _numbers_run(workdir: Path, fault: signal.Signals) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Source and sink under a supervisor; ``fault`` sent to the sink once it reads; returns the tally and the
    restarted sink's subscription stats."""
    spec = SupervisorSpec(strategy="one_for_one", intensity=100, period=60.0, children=[
        ChildSpec(SINK, (NumberSink, (str(workdir),)), heartbeat=HEARTBEAT),
        ChildSpec(SOURCE, (NumberSource, (str(workdir),)), heartbeat=HEARTBEAT),
    ])
    watch = _Watch()
    with ActorSystem() as asys:
        tree = Tree.of(asys)
        tree.events.listeners.append(watch.on_event)
        sup = start_supervisor(asys, spec, "chaos")
        try:
            sink = asys.ref(SINK)
            wait_until(lambda: sink.control("stats", timeout=10).get()["subscriptions"][0]["received"] > 50,
                       what="the sink reading the topic")
            os.kill(watch.pids[SINK], fault)
            assert watch.wait_restart(SINK, 4 * HEARTBEAT) is not None, "the sink was not restarted"
            # A publisher re-sends what it held for the sink at its next publish: let the flow go on past that.
            wait_until(lambda: sink.control("stats", timeout=10).get()["subscriptions"][0]["received"] > 400,
                       what="the restarted sink reading the topic")
            final = asys.ref(SOURCE).ask("finish", timeout=30).get()
            path = workdir / f"sink-{watch.pids[SINK]}.log"
            wait_until(lambda: f"S {final['sent']} " in path.read_text(), what="the sink handling the last number")
            subs = sink.control("stats", timeout=10).get()["subscriptions"]
            sup.stop()
        finally:
            tree.close()
    acked, _ = watermark(read_records(str(workdir), "source"))
    return tally_numbers(read_records(str(workdir), "sink"), acked), subs


def test_a_sink_hung_past_the_keep_all_stall_bound_has_its_drops_counted_not_lost(tmp_path: Path) -> None:
    # SIGSTOP: the sink is silent for its 3 s heartbeat deadline, then killed and restarted. The publisher
    # sends it a window (256 numbers, 1.3 s), waits 1 s, then drops for it, counted, until the restarted
    # sink reads; the window is re-sent to it. Those drops are the runtime's stall bound, not a loss.
    nums, subs = _numbers_run(tmp_path, signal.SIGSTOP)
    assert nums["sink_incarnations"] == 2
    assert nums["lost_topic"] == [] and nums["lost_tell"] == [], nums
    assert subs[0]["redelivered"] > 0  # the window held for the hung incarnation went to the next one
    assert nums["dropped_topic"] == subs[0]["dropped"] > 0, (nums, subs)


def test_a_killed_sink_drops_nothing_of_the_keep_all_topic(tmp_path: Path) -> None:
    # SIGKILL: restarted within ms; what was published meanwhile is held for the next incarnation.
    nums, subs = _numbers_run(tmp_path, signal.SIGKILL)
    assert nums["sink_incarnations"] == 2
    assert nums["lost_topic"] == [] and nums["lost_tell"] == [] and nums["dropped_topic"] == 0, nums
    assert subs[0]["dropped"] == 0, subs
