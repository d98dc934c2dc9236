"""End to end with a real root process: stop from another process, SIGTERM, give-up, no orphans."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from supervisor.client import find_runs, main, request
from tests.helpers import wait_until
from tests.supervisor.conftest import gone

ROOT = str(Path(__file__).resolve().parents[2])


class Root:
    def __init__(self, tmp: Path, mode: str = "basic") -> None:
        self.out = tmp / "pids.json"
        env = {**os.environ, "PYTHONPATH": ROOT, "EMBAGENTS_RUNS_DIR": os.environ["EMBAGENTS_RUNS_DIR"]}
        self.proc = subprocess.Popen([sys.executable, "-m", "tests.supervisor.rootproc", mode, str(self.out)],
                                     cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)

    def pids(self) -> dict:
        wait_until(lambda: self.out.exists() or self.proc.poll() is not None, 30, "the root to start")
        assert self.proc.poll() is None, self.proc.stderr.read().decode()[-3000:]
        return json.loads(self.out.read_text())

    def wait(self) -> int:
        _, err = self.proc.communicate(timeout=30)
        self.log = err.decode(errors="replace")
        return self.proc.returncode


@pytest.fixture
def start_root(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable[..., Root]]:
    monkeypatch.setenv("EMBAGENTS_RUNS_DIR", str(tmp_path / "runs"))
    roots: list[Root] = []

    def start(mode: str = "basic") -> Root:
        roots.append(Root(tmp_path, mode))
        return roots[-1]

    yield start
    for r in roots:
        if r.proc.poll() is None:
            r.proc.kill()
            r.proc.communicate()


def children(info: dict) -> list[int]:
    return [info[k] for k in ("echo", "cmd", "deep", "forkserver")]


def test_stop_from_another_process_is_clean(start_root: Callable[..., Root]) -> None:
    root = start_root()
    info = root.pids()
    [run] = find_runs()
    assert run["pid"] == root.proc.pid and run["system"] == "e2e-basic"
    rows = request(run["run_dir"], {"cmd": "status"})["rows"]
    assert [r["name"] for r in rows] == ["echo", "cmd", "inner", "deep"]
    assert main(["stop"]) == 0
    assert root.wait() == 0
    assert all(gone(p) for p in children(info))
    assert find_runs() == [] and not os.path.exists(info["run_dir"])


def test_sigterm_stops_the_run_in_reverse_order(start_root: Callable[..., Root]) -> None:
    root = start_root()
    info = root.pids()
    root.proc.send_signal(signal.SIGTERM)
    assert root.wait() == 0
    stopped = [line.split()[4] for line in root.log.splitlines() if " supervisor stopped " in line]
    assert stopped == ["root/inner/deep", "root/inner", "root/cmd", "root/echo"]
    assert all(gone(p) for p in children(info))


def test_a_root_that_gives_up_exits_with_status_1(start_root: Callable[..., Root]) -> None:
    root = start_root("giveup")
    root.pids()
    assert root.wait() == 1
    assert find_runs() == []


def test_no_orphans_when_the_root_is_sigkilled(start_root: Callable[..., Root]) -> None:
    root = start_root()
    info = root.pids()
    pids = children(info)
    assert not any(gone(p) for p in pids)
    root.proc.kill()
    root.wait()
    for p in pids:  # actors die with the fork server; the command by PR_SET_PDEATHSIG
        wait_until(lambda p=p: gone(p), 10, f"exit of {p}")
    wait_until(lambda: not os.path.exists(info["run_dir"]), 10, "the run directory's removal")
    assert find_runs() == []  # the stale announcement is noticed and removed
