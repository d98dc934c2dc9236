"""`embagents logs NAME [-f]`: each actor's lines, from its file in the run directory."""

from __future__ import annotations

import os
import select

from tests.embagents.fixtures.live_run import Run
from tests.helpers import wait_until


def test_logs_show_one_actors_lines(live_run: Run) -> None:
    assert live_run.cli("topic", "pub", "chatter", "String", "{data: log me}").returncode == 0
    out = wait_until(lambda: (o := live_run.cli("logs", "shout")).returncode == 0 and "heard log me" in o.stdout and o,
                     20, "shout's line in its log")
    lines = out.stdout.splitlines()
    assert all("[shout]" in x for x in lines)  # only shout's lines
    assert len(live_run.cli("logs", "shout", "-n", "1").stdout.splitlines()) == 1


def test_logs_follow_prints_new_lines(live_run: Run) -> None:
    follow = live_run.popen("logs", "shout", "-f", "-n", "0")
    try:
        assert follow.stdout is not None
        assert live_run.cli("topic", "pub", "chatter", "String", "{data: followed}").returncode == 0
        os.set_blocking(follow.stdout.fileno(), False)
        got: list[str] = []

        def seen() -> bool:
            if select.select([follow.stdout], [], [], 0.2)[0]:
                got.append(follow.stdout.read() or "")
            return "heard followed" in "".join(got)

        wait_until(seen, 20, "the new line in `logs -f`")
    finally:
        follow.terminate()
        follow.wait(10)


def test_logs_of_an_unknown_actor_name_the_known_ones(live_run: Run) -> None:
    out = live_run.cli("logs", "shuot")
    assert out.returncode == 1 and "no log for 'shuot'" in out.stderr
    assert "shout" in out.stderr and "talker" in out.stderr and "root" in out.stderr


def test_a_name_that_is_not_an_actors_log_is_refused(live_run: Run, tmp_path) -> None:
    from supervisor.client import pick_run

    logs = os.path.join(pick_run(live_run.id)["run_dir"], "logs")
    secret = tmp_path / "secret.log"
    secret.write_text("not the run's\n")
    for name in (os.path.relpath(tmp_path / "secret", logs), "../logs/shout", "shout/../talker"):
        out = live_run.cli("logs", name)
        assert out.returncode == 1 and f"no log for {name!r}" in out.stderr and "not the run's" not in out.stdout
        assert "shout" in out.stderr  # the known ones


def test_root_log_holds_the_start_up_lines(live_run: Run) -> None:
    out = live_run.cli("logs", "root")
    assert out.returncode == 0
    assert "supervising tools_test" in out.stdout and "system 'tools_test' running" in out.stdout
