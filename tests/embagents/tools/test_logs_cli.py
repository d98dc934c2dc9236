"""`embagents logs NAME [-f]`: each actor's lines, from its file in the run directory."""

from __future__ import annotations

import os
import select

from tests.embagents.tools.conftest import Run
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
