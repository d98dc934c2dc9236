"""`embagents topic list|echo|hz|pub` against a live run (the shared run of conftest.py)."""

from __future__ import annotations

import json
import os
import signal
import time

from tests.embagents.fixtures.live_run import Run
from tests.helpers import wait_until


def test_list_names_types_publishers_and_rates(live_run: Run) -> None:
    out = live_run.cli("topic", "list", "--json")
    assert out.returncode == 0, out.stderr
    rows = {r["name"]: r for r in json.loads(out.stdout)}
    assert {"chatter", "camera/image", "dets", "loud", "_supervisor.events"} <= set(rows)
    assert rows["chatter"]["type"] == "String" and rows["chatter"]["keep"] == "all"
    assert rows["chatter"]["publishers"] == ["talker"] and rows["chatter"]["subscribers"] >= 1
    assert rows["chatter"]["rate"] > 0  # shout reads it at 20 Hz
    table = live_run.cli("topic", "list").stdout
    assert "TOPIC" in table and "camera/image" in table and "Image" in table


def test_echo_prints_text_json_and_summarises_arrays(live_run: Run) -> None:
    out = live_run.cli("topic", "echo", "chatter", "-n", "2", "--json")
    assert out.returncode == 0, out.stderr
    lines = [json.loads(x) for x in out.stdout.splitlines()]
    assert len(lines) == 2 and all(x["data"].startswith("hello ") for x in lines)
    img = live_run.cli("topic", "echo", "camera/image", "-n", "1")
    assert "data: <array shape=(240, 320, 3) dtype=uint8>" in img.stdout and "encoding: rgb8" in img.stdout
    full = live_run.cli("topic", "echo", "dets", "-n", "1", "--json", "--full-arrays")
    assert json.loads(full.stdout.splitlines()[0])["boxes"] == [[100.0, 60.0, 220.0, 200.0]]


def test_hz_reports_rate_and_period_statistics(live_run: Run) -> None:
    out = live_run.cli("topic", "hz", "chatter", "--duration", "2.5")
    assert out.returncode == 0, out.stderr
    assert "average rate:" in out.stdout and "min:" in out.stdout and "std dev:" in out.stdout


def test_unknown_topic_names_the_known_ones(live_run: Run) -> None:
    for cmd in (("echo", "chatterr"), ("hz", "chatterr"), ("pub", "chatterr", "String", "{data: x}")):
        out = live_run.cli("topic", *cmd)
        assert out.returncode == 1
        assert "no topic 'chatterr'" in out.stderr and "chatter, " in out.stderr and "loud" in out.stderr


def test_pub_reaches_subscribers_once_and_at_a_rate(live_run: Run) -> None:
    echo = live_run.popen("topic", "echo", "loud", "--json", "--duration", "30")
    try:
        assert echo.stdout is not None
        echo.stdout.readline()  # it hears loud (the talker's hellos): its subscription is up
        out = live_run.cli("topic", "pub", "chatter", "String", "{data: hi there}", "-r", "5", "-t", "5")
        assert out.returncode == 0, out.stderr
        assert "published 5 String on chatter at 5 Hz" in out.stdout
        wait_until(lambda: json.loads(echo.stdout.readline())["data"] == "HI THERE", 20, "the published text, shouted")
    finally:
        echo.terminate()
        echo.wait(10)
    once = live_run.cli("topic", "pub", "chatter", "String", '{"data": "json too"}')
    assert once.returncode == 0 and "published String on chatter" in once.stdout


def test_pub_data_that_does_not_fit_names_the_field(live_run: Run) -> None:
    out = live_run.cli("topic", "pub", "chatter", "String", "{data: 5}")
    assert out.returncode == 1 and "field 'data' must be a str, got 5" in out.stderr
    out = live_run.cli("topic", "pub", "chatter", "String", "{colour: blue}")
    assert out.returncode == 1 and "String has no field 'colour'" in out.stderr and "data (str)" in out.stderr
    out = live_run.cli("topic", "pub", "chatter", "Image", "{}")
    assert out.returncode == 1 and "carries String, not Image" in out.stderr
    out = live_run.cli("topic", "pub", "chatter", "String", "{data: [1, 2")
    assert out.returncode == 1 and "neither YAML nor JSON" in out.stderr


def test_pub_takes_plain_text_for_a_string_and_says_how_to_quote_yaml(live_run: Run) -> None:
    echo = live_run.popen("topic", "echo", "loud", "--json", "--duration", "30")
    try:
        assert echo.stdout is not None
        echo.stdout.readline()
        out = live_run.cli("topic", "pub", "chatter", "String", "What is the capital of Japan?")
        assert out.returncode == 0, out.stderr
        wait_until(lambda: json.loads(echo.stdout.readline())["data"] == "WHAT IS THE CAPITAL OF JAPAN?", 20,
                   "the plain text, shouted")
    finally:
        echo.terminate()
        echo.wait(10)
    out = live_run.cli("topic", "pub", "chatter", "String", "{data: What is the capital of Japan?}")
    assert out.returncode == 1 and "neither YAML nor JSON" in out.stderr
    assert """'{data: "What is the capital of Japan?"}'""" in out.stderr
    assert "embagents topic pub chatter String 'What is the capital of Japan?'" in out.stderr


def test_call_lists_a_components_actions_not_its_internals(live_run: Run) -> None:
    out = live_run.cli("call", "shout", "nosuch")
    assert out.returncode == 1 and "has no action 'nosuch'; its actions: reconfigure, say" in out.stderr
    assert "set_system_failure" not in out.stderr and "on_activate" not in out.stderr
    said = live_run.cli("call", "shout", "say", "hi")
    assert said.returncode == 0 and said.stdout.strip() == "shout.say -> 'HI'", said.stderr


def test_a_paused_echo_drops_and_never_holds_publishers_back(live_run: Run) -> None:
    echo = live_run.popen("topic", "echo", "chatter", "--duration", "60")
    try:
        time.sleep(1.0)
        os.kill(echo.pid, signal.SIGSTOP)  # its terminal paused: it reads nothing
        def heard() -> int:
            rows = live_run.status()
            assert not rows["talker"].get("stalled")  # no keep-all subscriber holds it back
            return next(s["received"] for s in rows["shout"]["subscriptions"] if s["topic"] == "chatter")

        before = heard()
        time.sleep(3.0)
        assert heard() - before >= 30  # talker went on at 20 Hz
    finally:
        os.kill(echo.pid, signal.SIGCONT)
        echo.terminate()
        echo.wait(10)
