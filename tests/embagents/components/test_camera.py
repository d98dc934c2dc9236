"""The Camera on real opencv: a video file played (looping or not), a source that cannot be opened."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from embagents.components import Camera, CameraConfig, HealthStatus  # noqa: E402
from embagents.msgs import Image  # noqa: E402
from embagents.topic import Topic  # noqa: E402


def write_clip(path: Path, frames: int = 4, size: tuple[int, int] = (64, 48)) -> str:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, size)
    for i in range(frames):
        frame = np.zeros((size[1], size[0], 3), np.uint8)
        frame[:, :, 2] = 40 * (i + 1)  # red in BGR: the camera must hand out RGB
        writer.write(frame)
    writer.release()
    return str(path)


def camera(**config: Any) -> tuple[Camera, list[Image]]:
    cam = Camera(name="cam", outputs=[Topic("image", Image)], config=CameraConfig(**config), trigger=10.0)
    sent: list[Image] = []
    cam.attach(lambda topic, msg: sent.append(msg))
    return cam, sent


def test_a_video_file_plays_as_rgb_frames_at_the_asked_resolution_then_ends(tmp_path: Path) -> None:
    cam, sent = camera(source=write_clip(tmp_path / "clip.mp4"), width=32, height=24)
    for _ in range(6):
        cam.execute()
    assert len(sent) == 4 and cam.finished and cam.health_status == HealthStatus.HEALTHY
    assert sent[0].data.shape == (24, 32, 3) and sent[0].encoding == "rgb8"
    assert sent[0].data[..., 0].mean() > 30 and sent[0].data[..., 2].mean() < 10  # red stayed red


def test_a_looping_file_starts_again(tmp_path: Path) -> None:
    cam, sent = camera(source=write_clip(tmp_path / "clip.mp4"), loop=True)
    for _ in range(10):
        cam.execute()
    assert len(sent) == 10 and not cam.finished
    assert abs(int(sent[4].data[..., 0].mean()) - int(sent[0].data[..., 0].mean())) < 8  # frame 5 is frame 1


def test_a_camera_that_cannot_be_opened_reports_it_retries_with_backoff_and_recovers(tmp_path: Path) -> None:
    path = tmp_path / "later.mp4"
    cam, sent = camera(source=str(path), retry_s=0.01, retry_max_s=0.02)
    cam.execute()
    health = cam.health
    assert health.status == HealthStatus.SYSTEM_FAILURE and sent == []
    assert str(path) in health.text and "cannot be opened; check the path; retrying in 0.0 s" in health.text
    time.sleep(0.02)
    cam.execute()
    assert cam.health.status == HealthStatus.SYSTEM_FAILURE  # still failing, not crashed
    write_clip(path)
    time.sleep(0.03)
    cam.execute()
    assert cam.health.status == HealthStatus.HEALTHY and len(sent) == 1


def test_a_device_index_that_is_not_there_is_a_system_failure_not_a_crash() -> None:
    cam, sent = camera(source=97)
    cam.execute()
    assert cam.health.status == HealthStatus.SYSTEM_FAILURE and "camera device 97 cannot be opened" in cam.health.text
    assert "ls /dev/video*" in cam.health.text and sent == []
