"""embagents.live: a script drives a running system through one client (and the CLI goes through it too).

One real run (``embagents supervise``) serves every test here: a counter with slow and failing
actions, and a shout that upper-cases what it hears.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import textwrap
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from embagents.live import LiveRun, connect
from supervisor.client import ControlError
from tests.helpers import wait_until

SYSTEM = '''
import os
import time

from embagents import Component, String, System, Topic

said = Topic("said", String)
loud = Topic("loud", String)


class Counter(Component):
    """Actions for the client: bump counts, nap sleeps (after touching a file), fail raises."""

    def bump(self):
        self.n = getattr(self, "n", 0) + 1
        return self.n

    def count(self):
        return getattr(self, "n", 0)

    def nap(self, seconds, mark=None):
        if mark:
            open(mark, "w").close()
        time.sleep(seconds)
        return seconds

    def fail(self):
        raise ValueError("the counter refuses")


class Shout(Component):
    """Upper-cases what it hears on said onto loud."""

    def _execution_step(self, **inputs):
        self.publish("loud", String(data=inputs["said"].data.upper()))


system = System([Counter(name="counter"), Shout(name="shout", inputs=[said], outputs=[loud], trigger=said)],
                external=[said], name="live_test")
'''


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[LiveRun, dict[str, str]]]:
    folder = tmp_path_factory.mktemp("live")
    (folder / "system.py").write_text(textwrap.dedent(SYSTEM))
    env = {**os.environ, "EMBAGENTS_RUNS_DIR": str(folder / "runs")}
    with open(folder / "root.log", "wb") as out:
        proc = subprocess.Popen([sys.executable, "-m", "embagents.cli", "supervise", str(folder / "system.py")],
                                stdout=out, stderr=subprocess.STDOUT, env=env)
    os.environ["EMBAGENTS_RUNS_DIR"] = env["EMBAGENTS_RUNS_DIR"]  # connect() finds this run (restored below)
    live = None
    try:
        live = wait_until(lambda: _connected(proc), 90, "the run to announce itself", interval=0.2)
        live.wait_ready(60)
        yield live, env
    finally:
        if live is not None:
            live.close()
        os.environ.pop("EMBAGENTS_RUNS_DIR")
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        print((folder / "root.log").read_text()[-3000:])


def _connected(proc: subprocess.Popen[bytes]) -> LiveRun | None:
    assert proc.poll() is None, "the run ended before it answered"
    try:
        return connect()
    except ControlError:
        return None


def _cli(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "embagents.cli", *args], capture_output=True, text=True,
                          timeout=120, env=env)


def _quietly(fn: Any) -> Any:
    """``fn`` for a thread whose outcome the test does not need (its actor restarts under it)."""
    def run(*args: Any) -> None:
        with contextlib.suppress(ControlError):
            fn(*args)

    return run


def _rows(live: LiveRun) -> dict[str, dict[str, Any]]:
    return {r["name"]: r for r in live.status()["rows"]}


def test_two_hundred_calls_through_one_client(run: tuple[LiveRun, dict[str, str]]) -> None:
    live, _ = run
    first = live.call("counter", "bump")
    assert [live.call("counter", "bump") for _ in range(199)] == list(range(first + 1, first + 200))
    assert live.call("counter", "nap", 0, mark=None) == 0  # keyword arguments too


def test_status_rows_and_ready(run: tuple[LiveRun, dict[str, str]]) -> None:
    live, _ = run
    status = live.wait_ready(10)
    assert status["system"] == "live_test" and status["run_id"] == live.run_id
    rows = _rows(live)
    assert {"counter", "shout"} <= set(rows)
    assert rows["counter"]["status"] == "running" and rows["counter"]["lifecycle"] == "active"
    assert rows["counter"]["pid"] > 0 and rows["counter"]["pid"] != rows["shout"]["pid"]


def test_publish_then_receive_on_subscribe_and_echo(run: tuple[LiveRun, dict[str, str]]) -> None:
    live, _ = run
    heard: list[str] = []
    got = threading.Event()
    sub = live.subscribe("loud", lambda msg: (heard.append(msg.data), got.set()))
    messages = live.echo("loud", count=1, timeout=30)
    try:
        live.publish("said", "hello there")
        assert [m.data for m in messages] == ["HELLO THERE"]  # subscribed before the publish: not missed
        assert got.wait(30) and heard[0] == "HELLO THERE"
    finally:
        sub.close()
        messages.close()
    with pytest.raises(ControlError, match="no topic 'lout' in this run; its topics: .*loud"):
        live.subscribe("lout", print)
    with pytest.raises(ControlError, match="String has no field 'colour'"):
        live.publish("said", colour="blue")


def test_a_failed_action_is_one_line_and_its_traceback_rides_along(run: tuple[LiveRun, dict[str, str]]) -> None:
    live, env = run
    with pytest.raises(ControlError) as err:
        live.call("counter", "fail")
    assert str(err.value) == "counter.fail failed: ValueError: the counter refuses"
    assert err.value.reply is not None and "raise ValueError" in err.value.reply["traceback"]
    out = _cli(env, "call", "counter", "fail")
    assert out.returncode == 1 and out.stderr.strip().splitlines() == [
        "error: counter.fail failed: ValueError: the counter refuses (-v: its traceback)"]
    verbose = _cli(env, "call", "-v", "counter", "fail")
    assert verbose.returncode == 1 and "raise ValueError" in verbose.stderr and "Traceback" in verbose.stderr


def test_a_slow_action_leaves_status_and_topic_list_answering(run: tuple[LiveRun, dict[str, str]],
                                                              tmp_path: Path) -> None:
    live, env = run
    mark = tmp_path / "napping"
    slow = subprocess.Popen([sys.executable, "-m", "embagents.cli", "call", "counter", "nap", "8", str(mark)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        wait_until(mark.exists, 30, "the counter to begin its nap")
        # One request at a time at the root: these waited behind the nap and said "is it still running?".
        status = _cli(env, "status", "--json", "--timeout", "5")
        assert status.returncode == 0, status.stderr
        assert {r["name"] for r in json.loads(status.stdout)["rows"]} >= {"counter", "shout"}
        topics = _cli(env, "topic", "list", "--timeout", "5")
        assert topics.returncode == 0 and "loud" in topics.stdout, topics.stderr
        assert slow.poll() is None  # still napping
    finally:
        out, err = slow.communicate(timeout=60)
    assert slow.returncode == 0 and "counter.nap -> 8" in out, err


def test_a_call_reported_as_failed_never_runs_later(run: tuple[LiveRun, dict[str, str]], tmp_path: Path) -> None:
    live, _ = run
    before = live.call("counter", "count")
    mark = tmp_path / "napping"
    nap = threading.Thread(target=live.call, args=("counter", "nap", 3, str(mark)))
    nap.start()
    wait_until(mark.exists, 30, "the counter to begin its nap")
    with pytest.raises(ControlError, match="counter.bump did not answer within 0.5 s"):
        live.call("counter", "bump", timeout=0.5)  # it waits in the mailbox behind the nap
    nap.join(30)
    assert live.call("counter", "count") == before  # the bump was dropped, not run after the nap


def test_a_restart_reported_as_failed_never_happens_later(run: tuple[LiveRun, dict[str, str]],
                                                          tmp_path: Path) -> None:
    live, env = run
    pid = _rows(live)["shout"]["pid"]
    mark = tmp_path / "napping"
    # The counter naps in its handler: stopping it waits for the nap, so its restart holds the supervisor.
    napper = threading.Thread(target=_quietly(live.call), args=("counter", "nap", 3, str(mark)))
    napper.start()
    wait_until(mark.exists, 30, "the counter to begin its nap")
    slow = threading.Thread(target=live.request, args=({"cmd": "restart", "name": "counter"}, 60))
    slow.start()
    out = _cli(env, "restart", "shout", "--timeout", "1")  # queued behind the counter's restart
    assert out.returncode == 1 and "no answer" in out.stderr, out.stderr
    napper.join(30)
    slow.join(30)
    live.request({"cmd": "restart", "name": "counter"}, 60)  # a job after shout's: shout's has had its turn
    assert _rows(live)["shout"]["pid"] == pid
