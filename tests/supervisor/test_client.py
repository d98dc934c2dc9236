"""The client side: finding runs, requests, the status table, the small CLI."""

from __future__ import annotations

import json
import os
import pwd

import pytest

from actors import ActorSystem, UnsafeFolder
from supervisor import ChildSpec, SupervisorSpec, start_supervisor
from supervisor.client import ControlError, find_runs, format_status_table, main, pick_run, request
from supervisor.control import ControlServer, runs_dir
from tests.supervisor.workers import Echo

ROWS = [
    {"name": "camera", "supervisor": "root", "kind": "actor", "status": "running", "lifecycle": "active",
     "pid": 41822, "restarts": 0, "uptime": 192.0, "cpu_percent": 4.0, "rss_mb": 61.2, "mailbox": 0, "rate": 30.0,
     "drops": 7},
    {"name": "socat", "supervisor": "root/io", "kind": "command", "status": "restarting", "lifecycle": None,
     "pid": None, "restarts": 12, "uptime": 0.0, "cpu_percent": None, "rss_mb": None, "mailbox": None, "rate": None},
]


def test_format_status_table() -> None:
    lines = format_status_table(ROWS).splitlines()
    assert lines[0].split() == ["NAME", "SUPERVISOR", "KIND", "STATUS", "LIFECYCLE", "PID", "RESTARTS",
                                "UPTIME", "CPU%", "RSS", "MB", "MAILBOX", "MSG/S", "DROPS"]
    assert lines[1].split() == ["camera", "root", "actor", "running", "active", "41822", "0", "3m12s",
                                "4.0", "61.2", "0", "30.0", "7"]
    assert lines[2].split() == ["socat", "root/io", "command", "restarting", "-", "-", "12", "-", "-", "-", "-", "-", "-"]
    assert len({len(line) for line in lines[:2]}) == 1  # aligned
    assert format_status_table([]).startswith("NAME")


def test_an_actors_own_status_lines_follow_the_table_under_its_name() -> None:
    rows = [dict(ROWS[0], detail={"lines": ["zenoh connect tcp/127.0.0.1:7447: up, 1 link(s)"], "links": []}), ROWS[1]]
    lines = format_status_table(rows).splitlines()
    assert len(lines) == 4 and lines[3] == "camera: zenoh connect tcp/127.0.0.1:7447: up, 1 link(s)"


def test_find_runs_skips_and_removes_dead_announcements(system: ActorSystem) -> None:
    os.makedirs(runs_dir(), exist_ok=True)
    stale = os.path.join(runs_dir(), "dead.json")
    with open(stale, "w") as f:
        json.dump({"run_id": "dead", "run_dir": "/nonexistent", "pid": 2**22 + 12345, "started": 0}, f)
    control = ControlServer(system, "demo")
    try:
        runs = find_runs()
        assert [r["run_id"] for r in runs] == [system.run_id]
        assert not os.path.exists(stale)
        assert pick_run()["run_id"] == system.run_id
        assert pick_run("demo")["run_dir"] == system.run_dir
        with pytest.raises(ControlError, match="no live embagents run found matching 'other'"):
            pick_run("other")
    finally:
        control.close()
    with pytest.raises(ControlError, match="no live embagents run found"):
        pick_run()


def test_request_to_a_run_that_is_not_there_times_out(tmp_path) -> None:
    with pytest.raises(ControlError, match="no answer"):
        request(str(tmp_path), {"cmd": "status"}, timeout=0.2)


def test_main_status_json_restart_and_stop(system: ActorSystem, capsys: pytest.CaptureFixture[str]) -> None:
    start_supervisor(system, SupervisorSpec(children=[ChildSpec("a", Echo)]))
    stopped: list[bool] = []
    control = ControlServer(system, "demo", on_stop=lambda: stopped.append(True))
    try:
        assert main(["status", "--json"]) == 0
        out = json.loads(capsys.readouterr().out)
        assert [r["name"] for r in out["rows"]] == ["a"]
        assert main(["status"]) == 0
        text = capsys.readouterr().out
        assert text.startswith(f"demo  run {system.run_id}") and "\na " in text
        assert main(["restart", "a"]) == 0
        assert capsys.readouterr().out.startswith("restarted a (pid ")
        assert main(["restart", "zzz"]) == 1
        assert "no child named 'zzz'" in capsys.readouterr().err
        assert main(["stop"]) == 0
        assert stopped == [True]
    finally:
        control.close()
    assert main(["status"]) == 1


def test_status_refuses_an_announcement_folder_another_user_owns(
    tmp_path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # Another user could plant an announcement pointing at a socket of theirs.
    runs = tmp_path / "planted"
    runs.mkdir(mode=0o777)
    os.chmod(runs, 0o777)
    os.chown(runs, pwd.getpwnam("nobody").pw_uid, -1)
    monkeypatch.setenv("EMBAGENTS_RUNS_DIR", str(runs))
    assert main(["status"]) == 1
    err = capsys.readouterr().err
    assert f"refusing to use {runs}" in err and "belongs to uid" in err and f"rm -rf {runs}" in err
    with pytest.raises(UnsafeFolder):
        find_runs()
