"""Ready before publishing: a component is activated once the subscribers declared for its outputs are up,
and the run says when it is ready (`--ready-file`, the announcement, `embagents status --wait-ready`)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from embagents.supervision import build_spec, wiring
from embagents.system import load_system

SYSTEM = '''
import json, os, time
from embagents.components import Component
from embagents.system import SYSTEM_STOP
from embagents.msgs import String
from embagents.system import System
from embagents.topic import Topic

OUT = os.environ.get("LOSS_OUT", "")
N = int(os.environ.get("LOSS_N", "300"))
seq = Topic("seq", String, queue_size=1000, keep="all")
stop = Topic(SYSTEM_STOP, String)


class Source(Component):
    allowed_outputs = {"Required": [String]}

    def on_activate(self):
        self.n = 0

    def _execution_step(self, **inputs):
        self.publish(seq, String(data=str(self.n)))
        self.n += 1


class Slow(Component):
    def on_configure(self):
        time.sleep(0.5)


class Sink(Component):
    allowed_inputs = {"Required": [String]}
    allowed_outputs = {"Optional": [String]}

    def on_configure(self):
        if os.path.exists(OUT + ".crashed"):
            time.sleep(float(os.environ.get("SINK_RESTART_S", "0")))  # the replacement loads slowly

    def on_activate(self):
        self.got = []
        if os.environ.get("SINK_CRASHES") and not os.path.exists(OUT + ".crashed"):
            open(OUT + ".crashed", "w").close()
            self.call_later(0.3, lambda: os._exit(3))  # once started (a crash before is a failed start)

    def _execution_step(self, **inputs):
        self.got.append(int(inputs["seq"].data))
        if len(self.got) == N:
            with open(OUT, "w") as f:
                json.dump(self.got, f)
            self.publish(stop, String(data="done"))


source = Source(name="source", outputs=[seq], trigger=1000.0,
                wait_for_subscribers=os.environ.get("AT_ONCE") != "1")
slow = Slow(name="slow", trigger=None)
sink = Sink(name="sink", inputs=[seq], outputs=[stop], trigger=seq)
system = System([sink, slow, source] if os.environ.get("SINK_FIRST") else [source, slow, sink])
'''


def _write(tmp_path: Path) -> Path:
    path = tmp_path / "system.py"
    path.write_text(textwrap.dedent(SYSTEM))
    return path


def _env(tmp_path: Path, **extra: str) -> dict[str, str]:
    runs = tmp_path / "runs"
    runs.mkdir(mode=0o700, exist_ok=True)
    return {**os.environ, "LOSS_OUT": str(tmp_path / "got.json"), "EMBAGENTS_RUNS_DIR": str(runs), **extra}


def _supervise(path: Path, env: dict[str, str], *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "embagents.cli", "supervise", str(path), *args],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)


def test_a_source_listed_first_loses_nothing_on_a_keep_all_topic(tmp_path: Path) -> None:
    # The source publishes at 1 kHz from its first step; its subscriber starts 0.5 s later (after `slow`).
    proc = _supervise(_write(tmp_path), _env(tmp_path))
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 0, out
    got = json.loads((tmp_path / "got.json").read_text())
    assert got == list(range(len(got))), (got[:5], out[-2000:])  # from message 0, none missing


def test_the_run_says_when_it_is_ready(tmp_path: Path) -> None:
    ready = tmp_path / "ready.json"
    ready.write_text("an earlier run's")
    env = _env(tmp_path, LOSS_N="1000000000")
    proc = _supervise(_write(tmp_path), env, "--ready-file", str(ready))
    try:
        status = subprocess.run([sys.executable, "-m", "embagents.cli", "status", "--json", "--wait-ready", "60"],
                                capture_output=True, text=True, timeout=90, env=env)
        assert status.returncode == 0, status.stdout + status.stderr
        doc = json.loads(status.stdout)
        assert doc["ready"] is True
        assert {r["name"]: r["lifecycle"] for r in doc["rows"]} == {"source": "active", "slow": "active", "sink": "active"}
        assert json.loads(ready.read_text())["run_id"] == doc["run_id"]
        (announcement,) = [json.loads(p.read_text()) for p in (tmp_path / "runs").glob("*.json")]
        assert announcement["ready"] is True
    finally:
        subprocess.run([sys.executable, "-m", "embagents.cli", "stop"], capture_output=True, timeout=60, env=env)
        out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0, out
    assert "running (3 components, 0 models), ready" in out, out[-2000:]
    assert not ready.exists()  # the run is over


def test_status_wait_ready_gives_up_after_its_timeout(tmp_path: Path) -> None:
    status = subprocess.run([sys.executable, "-m", "embagents.cli", "status", "--wait-ready", "0.3"],
                            capture_output=True, text=True, timeout=60, env=_env(tmp_path))
    assert status.returncode == 1 and "no live embagents run found" in status.stderr, status.stderr


def test_a_subscriber_that_is_not_there_is_named_and_the_source_activated_anyway(tmp_path: Path) -> None:
    # The sink (listed first) crashes 0.3 s after its start, while `slow` starts; its replacement takes 8 s
    # to configure.
    env = _env(tmp_path, SINK_FIRST="1", SINK_CRASHES="1", SINK_RESTART_S="8", LOSS_N="1000000000")
    proc = _supervise(_write(tmp_path), env, "--wait-subscribers", "1")
    try:
        status = subprocess.run([sys.executable, "-m", "embagents.cli", "status", "--json", "--wait-ready", "60"],
                                capture_output=True, text=True, timeout=90, env=env)
    finally:
        subprocess.run([sys.executable, "-m", "embagents.cli", "stop"], capture_output=True, timeout=60, env=env)
        out, _ = proc.communicate(timeout=60)
    assert status.returncode == 0, status.stdout + status.stderr + out[-3000:]
    rows = {r["name"]: r for r in json.loads(status.stdout)["rows"]}
    assert rows["source"]["lifecycle"] == "active" and rows["sink"]["status"] in ("starting", "restarting"), out
    assert "component 'source': activated without waiting longer than 1 s for 'sink' (not running)" in out, out[-3000:]


def test_only_components_with_declared_subscribers_wait_and_a_source_may_start_at_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = _write(tmp_path)
    system = load_system(path)
    assert wiring(system) == {"source": {"seq": ("sink",)}}
    targets = {c.id: c.lifecycle for c in build_spec(system, str(path), activate_later=wiring(system)).children}
    assert targets == {"source": "inactive", "slow": "active", "sink": "active"}
    monkeypatch.setenv("AT_ONCE", "1")
    assert wiring(load_system(path)) == {}
