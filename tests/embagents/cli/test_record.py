"""`embagents record`: a supervised recorder writing MCAP (schemas, rotation, SIGKILL, refusals)."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest
from mcap.reader import make_reader

from embagents.cli.play import read_messages
from embagents.tools.mcap_codec import decode
from supervisor.client import ControlError, pick_run, request
from tests.embagents.fixtures.live_run import Run
from tests.helpers import wait_until


def _recorder(run: Run) -> dict:
    rows = run.status()
    return next(r for n, r in rows.items() if n.startswith("_record"))


def test_record_writes_every_topic_with_schemas_and_misses_nothing_of_keep_all(live_run: Run, tmp_path: Path) -> None:
    path = tmp_path / "all.mcap"
    out = live_run.cli("record", "-o", str(path), "--duration", "2")
    assert out.returncode == 0, out.stderr
    assert "recording 5 topics" in out.stdout and "messages on" in out.stdout
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        schemas = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        assert schemas["camera/image"] == "foxglove.RawImage" and schemas["chatter"] == "embagents.String"
        assert schemas["dets"] == "embagents.Detections"
        f.seek(0)
        said = [decode(s.name, m.data).data for s, _c, m in make_reader(f).iter_messages(topics=["chatter"])]
        f.seek(0)
        _s, _c, m = next(make_reader(f).iter_messages(topics=["camera/image"]))
        assert decode("foxglove.RawImage", m.data).data.shape == (240, 320, 3)
    numbers = [int(x.split()[1]) for x in said if x.startswith("hello ")]
    assert len(numbers) >= 20 and numbers == list(range(numbers[0], numbers[0] + len(numbers)))  # no gap


def test_second_record_on_the_same_file_is_refused(live_run: Run, tmp_path: Path) -> None:
    path = str(tmp_path / "once.mcap")
    assert live_run.cli("record", "-o", path, "--detach").returncode == 0
    try:
        again = live_run.cli("record", "-o", path, "--detach")
        assert again.returncode == 1 and "is already being recorded" in again.stderr
    finally:
        assert live_run.cli("record", "--stop", path).returncode == 0
    exists = live_run.cli("record", "-o", path, "--duration", "0.5")
    assert exists.returncode == 1 and "exists; pass --overwrite" in exists.stderr
    assert live_run.cli("record", "-o", path, "--duration", "0.5", "--overwrite").returncode == 0


def test_record_of_an_unknown_topic_names_the_known_ones(live_run: Run, tmp_path: Path) -> None:
    out = live_run.cli("record", "chatter", "nope", "-o", str(tmp_path / "x.mcap"))
    assert out.returncode == 1 and "no topic 'nope'" in out.stderr and "camera/image" in out.stderr
    assert not (tmp_path / "x.mcap").exists()


def test_rotation_by_size_keeps_the_newest_files(live_run: Run, tmp_path: Path) -> None:
    path = tmp_path / "rot.mcap"
    out = live_run.cli("record", "camera/image", "-o", str(path), "--max-size", "0.02", "--max-files", "2",
                       "--compression", "none", "--chunk-size", "8", "--duration", "2")
    assert out.returncode == 0, out.stderr
    files = sorted(p.name for p in tmp_path.iterdir())
    assert len(files) == 2 and "rot.mcap" not in files  # the oldest went
    for name in files:
        assert sum(1 for _ in read_messages(str(tmp_path / name), [])) >= 1


def test_rotation_by_duration(live_run: Run, tmp_path: Path) -> None:
    path = tmp_path / "timed.mcap"
    out = live_run.cli("record", "chatter", "-o", str(path), "--max-duration", "0.6", "--duration", "2.5")
    assert out.returncode == 0, out.stderr
    files = sorted(tmp_path.iterdir())
    assert len(files) >= 2 and out.stdout.count("messages on 1 topics") == len(files)  # each finished, with a summary


def test_sigkill_of_the_recorder_leaves_a_readable_file_and_it_goes_on(live_run: Run, tmp_path: Path) -> None:
    path = str(tmp_path / "killed.mcap")
    assert live_run.cli("record", "chatter", "-o", path, "--detach", "--chunk-size", "1").returncode == 0
    try:
        wait_until(lambda: os.path.getsize(path) > 4000, 20, "a few chunks written")
        first = _recorder(live_run)
        os.kill(live_run.status()["shout"]["pid"], signal.SIGKILL)  # another actor crashes
        wait_until(lambda: live_run.status()["shout"]["status"] == "running", 30, "shout restarted")
        assert _recorder(live_run)["pid"] == first["pid"]  # the recorder went on, untouched
        os.kill(first["pid"], signal.SIGKILL)
        wait_until(lambda: (r := _recorder(live_run))["pid"] != first["pid"] and r["status"] == "running", 30,
                   "the recorder restarted")
        assert live_run.status()["talker"]["restarts"] == 0  # nobody else noticed
        stopped: list = []
        said = [m.data for _t, _l, m in read_messages(path, stopped)]
        assert len(said) >= 10 and all(x.startswith(("hello", "HELLO")) or x for x in said)
        assert stopped and "cut short" in stopped[0].reason  # no footer: it was killed
    finally:
        out = live_run.cli("record", "--stop", path)
    assert out.returncode == 0 and "killed.1.mcap" in out.stdout  # the restarted recorder's own file


def test_recordings_are_owner_only_and_a_symlink_at_the_path_is_refused(live_run: Run, tmp_path: Path) -> None:
    path = tmp_path / "private.mcap"
    out = live_run.cli("record", "chatter", "-o", str(path), "--max-duration", "0.4", "--duration", "1.2")
    assert out.returncode == 0, out.stderr
    files = sorted(tmp_path.iterdir())
    assert len(files) >= 2 and all(f.stat().st_mode & 0o777 == 0o600 for f in files)  # rotations too
    target = tmp_path / "elsewhere" / "planted.mcap"  # where another user's dangling link points
    target.parent.mkdir()
    link = tmp_path / "link.mcap"
    link.symlink_to(target)
    for extra in ([], ["--overwrite"]):
        out = live_run.cli("record", "chatter", "-o", str(link), "--duration", "0.5", *extra)
        assert out.returncode == 1 and "is a symbolic link" in out.stderr, out.stderr
        assert not target.exists() and link.is_symlink()
    # The recorder itself (O_EXCL | O_NOFOLLOW), asked by another client than the CLI, or a link made after its check:
    run_dir = pick_run(live_run.id)["run_dir"]
    with pytest.raises(ControlError, match="is a symbolic link"):
        request(run_dir, {"cmd": "record_start", "path": str(link), "topics": ["chatter"]}, 20)
    assert not target.exists()
    assert live_run.cli("record", "-o", str(tmp_path / "after.mcap"), "--duration", "0.3").returncode == 0
