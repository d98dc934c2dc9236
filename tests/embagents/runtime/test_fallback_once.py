"""One failure, one restart: a fallback acts once per failing incarnation, under `embagents supervise`.

The worker below fails every step of a poisoned incarnation, fed at 200 Hz
(the issue's 50 Hz, and the rate at which the old code failed in every run
here), while its replacement spends 3 s in ``on_configure``: every report of
the dying incarnation used to run the fallback again (a second restart killed
the first replacement; a burst reached ``give_up`` before any replacement ran).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

from tests.helpers import wait_until

SYSTEM = '''
import os, time
from embagents.components import Component
from embagents.events import Fallback, restart
from embagents.msgs import String
from embagents.system import System
from embagents.topic import Topic

LOG = os.environ["ONCE_LOG"]
ticks = Topic("ticks", String)


def note(what):
    with open(LOG, "a") as f:
        f.write(f"{what} {os.getpid()}\\n")


class Feeder(Component):
    allowed_outputs = {"Required": [String]}

    def _execution_step(self, **inputs):
        self.publish(ticks, String(data="x"))


class Worker(Component):
    allowed_inputs = {"Required": [String]}

    def on_configure(self):
        note("configure")
        time.sleep(3.0)

    def on_activate(self):
        # Poisoned: every incarnation (FAIL_ALWAYS) or only the first.
        self.poisoned = os.environ.get("FAIL_ALWAYS") == "1" or not os.path.exists(LOG + ".poisoned")
        open(LOG + ".poisoned", "a").close()

    def _execution_step(self, **inputs):
        if self.poisoned:
            note("fail")
            raise RuntimeError("poisoned")
        note("ok")


system = System([
    Feeder(name="feeder", outputs=[ticks], trigger=200.0),
    Worker(name="worker", inputs=[ticks], trigger=ticks,
           fallback=Fallback(on_algorithm_fail=restart(), max_retries=int(os.environ["RETRIES"]))),
])
'''


def _lines(log: Path, what: str) -> list[str]:
    if not log.exists():
        return []
    return [line.split()[1] for line in log.read_text().splitlines() if line.startswith(what + " ")]


def _supervise(tmp_path: Path, **env: str) -> tuple[subprocess.Popen[str], Path]:
    path = tmp_path / "system.py"
    path.write_text(textwrap.dedent(SYSTEM))
    log = tmp_path / "worker.log"
    out = open(tmp_path / "out.txt", "w")  # noqa: SIM115 - the child writes it until the end
    proc = subprocess.Popen([sys.executable, "-m", "embagents.cli", "supervise", str(path)], stdout=out,
                            stderr=subprocess.STDOUT, text=True, env={**os.environ, "ONCE_LOG": str(log), **env})
    return proc, log


def _stop(proc: subprocess.Popen[str], tmp_path: Path) -> str:
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=30) == 0
    return (tmp_path / "out.txt").read_text()


def test_an_incarnation_failing_at_200_hz_while_its_replacement_loads_is_restarted_once(tmp_path: Path) -> None:
    proc, log = _supervise(tmp_path, RETRIES="3")
    try:
        ok = wait_until(lambda: _lines(log, "ok"), timeout=60, what="a healthy step of the replacement")
        # A second restart decided on a stale report would come right after the first one ended.
        wait_until(lambda: len(_lines(log, "ok")) >= 400, timeout=30, what="two seconds of healthy steps")
    finally:
        out = _stop(proc, tmp_path)
    configured = _lines(log, "configure")
    assert len(configured) == 2, out[-3000:]  # the first incarnation and its one replacement
    assert set(_lines(log, "ok")) == {configured[1]} == set(ok)
    assert out.count("action restart on worker") == 1, out[-3000:]


def test_give_up_comes_only_after_max_retries_incarnations_failed(tmp_path: Path) -> None:
    proc, log = _supervise(tmp_path, RETRIES="2", FAIL_ALWAYS="1")
    try:
        wait_until(lambda: "give_up worker" in (tmp_path / "out.txt").read_text(), timeout=60, what="give_up")
    finally:
        out = _stop(proc, tmp_path)
    assert len(_lines(log, "configure")) == 3, out[-3000:]  # two restarts, then the third failure gave up
    assert len(set(_lines(log, "fail"))) == 3, out[-3000:]  # each incarnation failed before the next action
    assert out.count("action restart on worker") == 2 and out.count("action give_up on worker") == 1, out[-3000:]
