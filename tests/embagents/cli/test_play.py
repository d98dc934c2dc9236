"""`embagents play`: a recording published into the live run; cut and corrupt files."""

from __future__ import annotations

import json
import time
from pathlib import Path

from embagents.msgs import String
from embagents.tools.recorder import _File
from tests.embagents.fixtures.live_run import Run
from tests.helpers import wait_until


def _recording(path: Path, texts: list[str], gap_s: float = 0.05, topic: str = "chatter") -> None:
    from embagents.tools.mcap_codec import kind_of

    f = _File(str(path), "lz4", chunk_bytes=64)
    t0 = time.time_ns()
    for i, text in enumerate(texts):
        t = t0 + int(i * gap_s * 1e9)
        f.writer.add_message(f.channel(topic, String), log_time=t, publish_time=t,
                             data=kind_of(String).encode(String(data=text)))
    f.close()


def _played(run: Run, args: list[str], want: str, stdin: str | None = None) -> None:
    echo = run.popen("topic", "echo", "loud", "--json", "--duration", "40")
    try:
        assert echo.stdout is not None
        echo.stdout.readline()  # it hears loud (the talker's hellos): its subscription is up
        out = run.cli("play", *args, stdin=stdin)
        assert out.returncode == 0, out.stderr
        wait_until(lambda: json.loads(echo.stdout.readline())["data"] == want, 20, f"{want} on loud")
    finally:
        echo.terminate()
        echo.wait(10)


def test_play_publishes_the_recording_at_recorded_timing_faster_and_stepped(live_run: Run, tmp_path: Path) -> None:
    path = tmp_path / "said.mcap"
    _recording(path, [f"played {i}" for i in range(5)])
    _played(live_run, [str(path), "--all"], "PLAYED 4")  # chatter is the talker's too: --all
    _played(live_run, [str(path), "--rate", "3", "--all"], "PLAYED 4")
    _played(live_run, [str(path), "--fast", "--topics", "chatter"], "PLAYED 4")  # named: played
    _played(live_run, [str(path), "--step", "--all"], "PLAYED 2", stdin="\n" * 5)


def test_a_cut_file_plays_what_is_readable_and_says_where_it_stopped(live_run: Run, tmp_path: Path) -> None:
    path = tmp_path / "whole.mcap"
    _recording(path, [f"part {i}" for i in range(50)])
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    out = live_run.cli("play", str(cut), "--fast", "--all")
    assert out.returncode == 1
    played = int(out.stdout.split()[1])
    assert 0 < played < 50
    assert f"stopped at byte {len(data) // 2} of {len(data) // 2}" in out.stderr and "cut short" in out.stderr
    assert "after the message on 'chatter'" in out.stderr


def test_a_corrupt_file_is_refused_with_where_and_why(live_run: Run, tmp_path: Path) -> None:
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all" * 10)
    out = live_run.cli("play", str(junk))
    assert out.returncode == 1 and "stopped at byte 0" in out.stderr and "not an MCAP file" in out.stderr
    for text in ("hello\n", "", "{}"):  # short files of another kind are not "cut short" recordings
        junk.write_text(text)
        out = live_run.cli("play", str(junk))
        assert out.returncode == 1 and "not an MCAP file" in out.stderr and "cut short" not in out.stderr, out.stderr
    missing = live_run.cli("play", str(tmp_path / "none.mcap"))
    assert missing.returncode == 1 and "none.mcap" in missing.stderr


def test_topics_the_run_publishes_itself_are_skipped_and_named_unless_all(live_run: Run, tmp_path: Path) -> None:
    path = tmp_path / "both.mcap"
    _recording(path, ["REPLAYED ANSWER"] * 3, gap_s=0.01, topic="loud")  # shout's output, as a chat's answers
    echo = live_run.popen("topic", "echo", "loud", "--json", "--duration", "6")
    try:
        assert echo.stdout is not None
        echo.stdout.readline()
        out = live_run.cli("play", str(path), "--fast")
        assert out.returncode == 0, out.stderr
        assert out.stdout.startswith("played 0 messages")
        assert "skipped loud (3 messages: published by shout; --all plays it too)" in out.stderr
        heard = echo.communicate(timeout=30)[0]
    finally:
        echo.kill()
    assert "REPLAYED ANSWER" not in heard
    out = live_run.cli("play", str(path), "--fast", "--all")
    assert out.returncode == 0 and out.stdout.startswith("played 3 messages") and "skipped" not in out.stderr


def test_system_stop_and_undeclared_topics_are_skipped_unless_named(live_run: Run, tmp_path: Path) -> None:
    stop, other = tmp_path / "stop.mcap", tmp_path / "other.mcap"
    _recording(stop, ["stop"], topic="system_stop")
    _recording(other, ["x", "y"], topic="not_in_this_run")
    out = live_run.cli("play", str(stop), str(other), "--fast")
    assert out.returncode == 0, out.stderr
    assert "skipped system_stop (1 messages: it would stop the run" in out.stderr
    assert "skipped not_in_this_run (2 messages: not a topic of this run" in out.stderr
    time.sleep(1.0)
    assert live_run.proc.poll() is None and live_run.cli("status").returncode == 0  # still running
    named = live_run.cli("play", str(other), "--fast", "--topics", "not_in_this_run")
    assert named.returncode == 0 and named.stdout.startswith("played 2 messages") and "not declared" in named.stderr
