"""`embagents status | restart | stop` against a live `embagents supervise` run."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

from tests.helpers import wait_until

SYSTEM = '''
from embagents import Component, String, System, Topic

class Idle(Component):
    allowed_inputs = {"Optional": [String]}

system = System([Idle(name="one", trigger=None), Idle(name="two", trigger=None)], name="ctl_test")
'''


def _cli(*args: str, run: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "embagents.cli", *args, "--run", run],
                          capture_output=True, text=True, timeout=60)


def test_status_restart_stop(tmp_path: Path) -> None:
    path = tmp_path / "system.py"
    path.write_text(textwrap.dedent(SYSTEM))
    sup = subprocess.Popen([sys.executable, "-m", "embagents.cli", "supervise", str(path)],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        run = str(sup.pid)

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
    finally:
        if sup.poll() is None:
            sup.kill()
        sup.communicate()
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
