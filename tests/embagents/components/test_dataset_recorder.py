"""The DatasetRecorder writes LeRobot v3 datasets: read back with pyarrow and PyAV's decoder, frame for frame.

LeRobot itself needs torch (not installable here): the layout is checked
against its documented v3.0 schema (meta/info.json, meta/stats.json,
meta/tasks.parquet, meta/episodes, data/, videos/).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

pa = pytest.importorskip("pyarrow")
av = pytest.importorskip("av")
import pyarrow.parquet as pq  # noqa: E402

from embagents.components import (  # noqa: E402
    ComponentError,
    DatasetRecorder,
    DatasetRecorderConfig,
    HealthStatus,
)
from embagents.components.dataset_recorder import MARK  # noqa: E402
from embagents.msgs import Image, JointState, String  # noqa: E402
from embagents.topic import Topic  # noqa: E402

JOINTS = ["j1", "j2", "j3"]
states, command, camera, episode = (Topic("arm/joint_states", JointState), Topic("arm/command", JointState),
                                    Topic("camera/image", Image), Topic("recorder/episode", String))


def recorder(root: Path, **config: object) -> DatasetRecorder:
    rec = DatasetRecorder(name="recorder", inputs=[states, command, camera, episode],
                          config=DatasetRecorderConfig(root=str(root), fps=10.0, camera_inputs_map={"front": camera.name},
                                                       **config))  # type: ignore[arg-type]
    rec.attach(lambda topic, msg: None)
    return rec


def frame(i: int) -> np.ndarray:
    """A frame that tells its index: a flat colour per index, and a white corner."""
    img = np.zeros((48, 64, 3), np.uint8)
    img[:] = (i * 17 % 256, 255 - i * 9 % 256, 80)
    img[:8, :8] = 255
    return img


def feed(rec: DatasetRecorder, n: int, start: int = 0, camera_at: float | None = None) -> list[np.ndarray]:
    frames = []
    for i in range(start, start + n):
        q = np.array([0.1 * i, -0.1 * i, 0.01 * i])
        rec.on_message(states.name, JointState(name=list(reversed(JOINTS)), position=q[::-1]))  # any order
        rec.on_message(command.name, JointState(name=JOINTS, position=q + 0.5))
        if camera_at is None:
            frames.append(frame(i))
            rec.on_message(camera.name, Image(data=frames[-1]))
        rec.execute()
    return frames


def video(path: Path) -> list[np.ndarray]:
    with av.open(str(path)) as c:
        return [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]


def test_an_episode_is_written_in_lerobots_v3_layout_and_reads_back_frame_for_frame(tmp_path: Path) -> None:
    root = tmp_path / "ds"
    rec = recorder(root, joint_names=JOINTS)
    rec.on_configure()
    assert rec.start_episode("pick the cup")["recording"]
    sent = feed(rec, 15)
    assert rec.end_episode()["total_frames"] == 15
    data = pq.read_table(root / "data" / "chunk-000" / "file-000.parquet").to_pydict()
    assert data["frame_index"] == list(range(15)) and data["index"] == list(range(15))
    assert data["episode_index"] == [0] * 15 and data["task_index"] == [0] * 15
    np.testing.assert_allclose(data["timestamp"], np.arange(15) / 10.0, atol=1e-6)
    np.testing.assert_allclose(data["observation.state"][4], [0.4, -0.4, 0.04], rtol=1e-6)  # in joint_names order
    np.testing.assert_allclose(data["action"][4], [0.9, 0.1, 0.54], rtol=1e-6)
    frames = video(root / "videos" / "observation.images.front" / "chunk-000" / "file-000.mp4")
    assert len(frames) == 15
    for got, want in zip(frames, sent, strict=True):  # h264 is lossy: close, and each frame is its own
        assert float(np.abs(got.astype(int) - want.astype(int)).mean()) < 4.0
    info = json.loads((root / "meta" / "info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["fps"] == 10.0 and info["splits"] == {"train": "0:1"}
    assert (info["total_episodes"], info["total_frames"], info["total_tasks"]) == (1, 15, 1)
    assert info["features"]["observation.state"] == {"dtype": "float32", "shape": [3], "names": JOINTS}
    cam = info["features"]["observation.images.front"]
    assert cam["dtype"] == "video" and cam["shape"] == [48, 64, 3] and cam["info"]["video.codec"] == "h264"
    assert info["data_path"].format(chunk_index=0, file_index=0) == "data/chunk-000/file-000.parquet"
    assert info["video_path"].format(video_key="observation.images.front", chunk_index=0, file_index=0) == \
        "videos/observation.images.front/chunk-000/file-000.mp4"
    stats = json.loads((root / "meta" / "stats.json").read_text())
    assert stats["observation.state"]["max"] == pytest.approx([1.4, 0.0, 0.14], rel=1e-5)
    assert stats["observation.state"]["count"] == [15]
    assert np.array(stats["observation.images.front"]["mean"]).shape == (3, 1, 1)  # per channel, in [0, 1]
    assert 0.0 <= stats["observation.images.front"]["min"][0][0][0] <= stats["observation.images.front"]["max"][0][0][0] <= 1
    assert pq.read_table(root / "meta" / "tasks.parquet").to_pylist() == [{"task_index": 0, "task": "pick the cup"}]
    (row,) = pq.read_table(root / "meta" / "episodes" / "chunk-000" / "file-000.parquet").to_pylist()
    assert row["length"] == 15 and row["tasks"] == ["pick the cup"] and row["embagents/ended_by"] == "call"
    assert (row["dataset_from_index"], row["dataset_to_index"]) == (0, 15)
    assert row["videos/observation.images.front/to_timestamp"] == pytest.approx(1.5)
    assert row["stats/action/min"] == pytest.approx([0.5, -0.9, 0.5], rel=1e-5)
    rec.on_shutdown()
    assert not (root / "meta" / MARK).exists()  # finished: another run may not append to it


def test_episodes_follow_one_another_on_a_topic_and_the_stats_cover_them_all(tmp_path: Path) -> None:
    root = tmp_path / "ds"
    rec = recorder(root)
    rec.on_configure()
    rec.on_message(episode.name, String("pick the cup"))
    feed(rec, 5)
    rec.on_message(episode.name, String("place it"))  # a new task ends the one running
    feed(rec, 7, start=5)
    rec.on_message(episode.name, String("end"))
    info = json.loads((root / "meta" / "info.json").read_text())
    assert (info["total_episodes"], info["total_frames"], info["total_tasks"]) == (2, 12, 2)
    assert info["splits"] == {"train": "0:2"}
    second = pq.read_table(root / "data" / "chunk-000" / "file-001.parquet").to_pydict()
    assert second["index"] == list(range(5, 12)) and second["frame_index"] == list(range(7))
    assert second["episode_index"] == [1] * 7 and second["task_index"] == [1] * 7
    rows = pq.read_table(root / "meta" / "episodes" / "chunk-000" / "file-000.parquet").to_pylist()
    assert [r["embagents/ended_by"] for r in rows] == ["replaced", "topic"]
    stats = json.loads((root / "meta" / "stats.json").read_text())
    assert stats["index"]["min"] == [0.0] and stats["index"]["max"] == [11.0] and stats["index"]["count"] == [12]
    assert stats["index"]["mean"] == pytest.approx([5.5])
    assert stats["index"]["std"] == pytest.approx([np.arange(12).std()])
    rec.on_shutdown()


def test_an_existing_directory_is_refused_unless_overwrite(tmp_path: Path) -> None:
    root = tmp_path / "ds"
    (root / "data").mkdir(parents=True)
    (root / "data" / "keep.txt").write_text("someone's")
    with pytest.raises(ComponentError, match=f"dataset directory {root} exists; record to a new one .* overwrite=True"):
        recorder(root)  # so `embagents check` and `supervise` refuse it before anything runs
    assert (root / "data" / "keep.txt").exists()  # nothing lost
    rec = recorder(root, overwrite=True)
    rec.on_configure()
    assert not (root / "data" / "keep.txt").exists() and (root / "meta" / MARK).exists()
    rec.on_shutdown()


def test_a_restarted_recorder_goes_on_after_the_episodes_already_written(tmp_path: Path) -> None:
    root = tmp_path / "ds"
    first = recorder(root)
    first.on_configure()
    first.start_episode("pick")
    feed(first, 4)
    first.end_episode()  # then the process is killed: no on_shutdown, the mark stays
    again = recorder(root)
    assert again.validate() == []
    again.on_configure()
    again.start_episode("pick")
    feed(again, 3)
    assert again.end_episode()["episodes"] == 2
    info = json.loads((root / "meta" / "info.json").read_text())
    assert (info["total_episodes"], info["total_frames"], info["total_tasks"]) == (2, 7, 1)
    assert pq.read_table(root / "data" / "chunk-000" / "file-001.parquet").to_pydict()["index"] == [4, 5, 6]
    again.on_shutdown()


def test_a_camera_that_stops_mid_episode_ends_the_episode_and_marks_it(tmp_path: Path) -> None:
    root = tmp_path / "ds"
    rec = recorder(root, camera_timeout_s=0.5)
    rec.on_configure()
    rec.start_episode("pick")
    feed(rec, 6)
    rec.on_message(camera.name, Image(data=frame(6)), now=time.monotonic() - 2.0)  # its last frame, 2 s ago
    feed(rec, 3, start=7, camera_at=0.0)  # states and commands go on, the camera does not
    status = rec.status()
    assert not status["recording"] and status["episodes"] == 1
    (row,) = pq.read_table(root / "meta" / "episodes" / "chunk-000" / "file-000.parquet").to_pylist()
    assert row["embagents/ended_by"] == "camera 'front' stopped" and row["length"] == 6
    assert len(video(root / "videos" / "observation.images.front" / "chunk-000" / "file-000.mp4")) == 6
    assert rec.health.status == HealthStatus.SYSTEM_FAILURE and "camera 'front' (camera/image) stopped" in rec.health.text
    rec.on_shutdown()
