"""`embagents status | restart | stop` against a live `embagents supervise` run."""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator
from pathlib import Path

from tests.helpers import wait_until

SYSTEM = '''
from embagents import Component, String, System, Topic

class Idle(Component):
    allowed_inputs = {"Optional": [String]}

system = System([Idle(name="one", trigger=None), Idle(name="two", trigger=None)], name="ctl_test")
'''


@contextlib.contextmanager
def _supervised(tmp_path: Path, source: str) -> Iterator[tuple[subprocess.Popen[str], str]]:
    """``embagents supervise`` of ``source`` as a system file: the process and its run id (its pid); killed after."""
    path = tmp_path / "system.py"
    path.write_text(textwrap.dedent(source))
    sup = subprocess.Popen([sys.executable, "-m", "embagents.cli", "supervise", str(path)],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        yield sup, str(sup.pid)
    finally:
        if sup.poll() is None:
            sup.kill()
        sup.communicate()


def _cli(*args: str, run: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "embagents.cli", *args, "--run", run],
                          capture_output=True, text=True, timeout=60)


def test_status_restart_stop(tmp_path: Path) -> None:
    with _supervised(tmp_path, SYSTEM) as (sup, run):

        def status() -> dict | None:
            out = _cli("status", "--json", run=run)
            return json.loads(out.stdout) if out.returncode == 0 else None

        st = wait_until(status, 60)
        assert st is not None and st["system"] == "ctl_test"
        rows = {r["name"]: r for r in st["rows"]}
        assert set(rows) == {"one", "two"}
        assert all(r["status"] == "running" and r["pid"] and r["restarts"] == 0 for r in rows.values())
        table = _cli("status", run=run).stdout
        assert "NAME" in table and "one" in table and "MAILBOX" in table

        out = _cli("restart", "two", run=run)
        assert out.returncode == 0, out.stderr
        rows = {r["name"]: r for r in status()["rows"]}
        assert rows["two"]["restarts"] == 1 and rows["two"]["pid"] != st["rows"][1]["pid"]

        bad = _cli("restart", "nobody", run=run)
        assert bad.returncode == 1 and "nobody" in bad.stderr

        assert _cli("stop", run=run).returncode == 0
        assert sup.wait(timeout=30) == 0
    time.sleep(0.2)
    assert not any(f.endswith(".json") and str(sup.pid) in open(os.path.join(d, f)).read()
                   for d in [f"/tmp/embagents-{os.getuid()}/runs"] if os.path.isdir(d) for f in os.listdir(d))


def test_status_without_a_run_says_how_to_start_one(tmp_path: Path) -> None:
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "status", "--run", "no-such-run"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 1 and "no-such-run" in out.stderr


def test_status_json_without_a_run_is_a_json_error_on_stdout(tmp_path: Path) -> None:
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "status", "--json"], capture_output=True, text=True,
                         timeout=60, env={**os.environ, "EMBAGENTS_RUNS_DIR": str(tmp_path / "runs")})
    assert out.returncode == 1
    reply = json.loads(out.stdout)
    assert reply["ok"] is False and "no live embagents run found" in reply["error"]
    assert "embagents supervise system.py" in reply["error"]


VOICE_SYSTEM = '''
from embagents import Component, System, Topic
from embagents.msgs import VoiceStage

stages = Topic("voice_stages", VoiceStage, keep="all", queue_size=100)
STEPS = (("end_of_speech", 0.0), ("end_of_turn", 0.2), ("transcript", 0.3), ("llm_first_token", 0.45),
         ("tts_first_audio", 0.6), ("speaker_start", 0.65))


class Turns(Component):
    """A voice turn's stages every step, the later ones 100 ms slower each turn (as voice components publish them)."""

    allowed_outputs = {"Required": [VoiceStage]}

    def __init__(self, **kw):
        self.sent = 0
        super().__init__(**kw)

    def _execution_step(self, **inputs):
        if self.sent < 40:
            t0 = 1000.0 + 10 * self.sent
            for stage, dt in STEPS:
                late = 0.1 * self.sent if stage in ("tts_first_audio", "speaker_start") else 0.0
                self.publish(stages, VoiceStage(stage=stage, stamp=t0 + dt + late, source="turns"))
            self.sent += 1


system = System([Turns(name="turns", outputs=[stages], trigger=20.0)], name="voice_status_test")
'''


def test_status_shows_the_voice_stages_published_on_a_voice_stage_topic(tmp_path: Path) -> None:
    with _supervised(tmp_path, VOICE_SYSTEM) as (sup, run):

        def voice() -> dict | None:
            out = _cli("status", "--json", run=run)
            got = json.loads(out.stdout)["voice"] if out.returncode == 0 else None
            return got if got and got["turns"] >= 40 else None

        got = wait_until(voice, 60)
        assert got is not None and got["topics"] == ["voice_stages"]
        latest, p50 = got["latest"], got["p50"]
        assert latest["eou_delay"] == 200.0 and latest["transcription_delay"] == 100.0 and latest["ttft"] == 150.0
        # The turn the root heard last is the 40th: its first audio came 3.9 s later than the first turn's.
        assert latest["ttfb"] == 150.0 + 3900.0 and latest["playout_delay"] == 50.0
        assert latest["total"] == 650.0 + 3900.0
        assert p50["eou_delay"] == 200.0 and p50["ttfb"] == 150.0 + 1950.0
        table = _cli("status", run=run).stdout
        assert "voice stages (40 turns, on voice_stages):" in table, table
        lines = table.splitlines()
        head = next(i for i, line in enumerate(lines) if line.startswith("voice stages"))
        assert lines[head + 1].split() == ["eou_delay", "transcription_delay", "ttft", "ttfb", "playout_delay", "total"]
        assert lines[head + 2].split()[:3] == ["latest", "200", "ms"] and "4550 ms" in lines[head + 2]
        assert lines[head + 3].split()[:3] == ["p50", "200", "ms"]
        assert _cli("stop", run=run).returncode == 0
        assert sup.wait(timeout=30) == 0


def test_status_of_a_system_without_voice_stages_shows_no_voice_lines(tmp_path: Path) -> None:
    with _supervised(tmp_path, SYSTEM) as (sup, run):
        st = wait_until(lambda: (out := _cli("status", "--json", run=run)).returncode == 0 and json.loads(out.stdout), 60)
        assert st["voice"] == {"topics": [], "turns": 0, "latest": {}, "p50": {}}
        table = _cli("status", run=run).stdout
        assert "NAME" in table and "voice stages" not in table
        assert _cli("stop", run=run).returncode == 0
        assert sup.wait(timeout=30) == 0
