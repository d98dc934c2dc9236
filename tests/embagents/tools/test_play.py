"""`embagents play`: a recording published into the live run; cut and corrupt files."""

from __future__ import annotations

import json
import time
from pathlib import Path

from embagents.msgs import String
from embagents.tools.recorder import _File
from tests.embagents.tools.conftest import Run
from tests.helpers import wait_until


def _recording(path: Path, texts: list[str], gap_s: float = 0.05) -> None:
    from embagents.tools.mcap_codec import kind_of

    f = _File(str(path), "lz4", chunk_bytes=64)
    t0 = time.time_ns()
    for i, text in enumerate(texts):
        t = t0 + int(i * gap_s * 1e9)
        f.writer.add_message(f.channel("chatter", String), log_time=t, publish_time=t,
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
    _played(live_run, [str(path)], "PLAYED 4")
    _played(live_run, [str(path), "--rate", "3"], "PLAYED 4")
    _played(live_run, [str(path), "--fast"], "PLAYED 4")
    _played(live_run, [str(path), "--step"], "PLAYED 2", stdin="\n" * 5)


def test_a_cut_file_plays_what_is_readable_and_says_where_it_stopped(live_run: Run, tmp_path: Path) -> None:
    path = tmp_path / "whole.mcap"
    _recording(path, [f"part {i}" for i in range(50)])
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    out = live_run.cli("play", str(cut), "--fast")
    assert out.returncode == 1
    played = int(out.stdout.split()[1])
    assert 0 < played < 50
    assert f"stopped at byte {len(data) // 2} of {len(data) // 2}" in out.stderr and "cut short" in out.stderr
    assert "after the message on 'chatter'" in out.stderr


def test_a_corrupt_file_is_refused_with_where_and_why(live_run: Run, tmp_path: Path) -> None:
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all" * 10)
    out = live_run.cli("play", str(junk))
    assert out.returncode == 1 and "stopped at byte" in out.stderr and "InvalidMagic" in out.stderr
    missing = live_run.cli("play", str(tmp_path / "none.mcap"))
    assert missing.returncode == 1 and "none.mcap" in missing.stderr
