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


# --- still images: real photos (scikit-image's data files) ------------------------------


@pytest.fixture
def photos(tmp_path: Path) -> Path:
    """A folder with two real photos (astronaut 512x512, chelsea the cat 451x300) and a file that is no image."""
    skimage = pytest.importorskip("skimage")
    data = Path(skimage.__file__).parent / "data"
    folder = tmp_path / "photos"
    folder.mkdir()
    for name in ("astronaut.png", "chelsea.png"):
        (folder / name).write_bytes((data / name).read_bytes())
    (folder / "notes.txt").write_text("not a photo")
    return folder


def test_a_folder_of_photos_plays_in_name_order_once_then_ends(photos: Path) -> None:
    cam, sent = camera(source=str(photos))
    for _ in range(4):
        cam.execute()
    assert [m.data.shape for m in sent] == [(512, 512, 3), (300, 451, 3)] and cam.finished
    assert cam.health_status == HealthStatus.HEALTHY and sent[0].encoding == "rgb8"
    astronaut = cv2.cvtColor(cv2.imread(str(photos / "astronaut.png")), cv2.COLOR_BGR2RGB)
    assert np.array_equal(sent[0].data, astronaut)  # RGB, as the file holds it


def test_a_glob_loops_and_a_single_photo_is_resized(photos: Path) -> None:
    cam, sent = camera(source=str(photos / "*.png"), loop=True)
    for _ in range(5):
        cam.execute()
    assert [m.data.shape[:2] for m in sent] == [(512, 512), (300, 451)] * 2 + [(512, 512)] and not cam.finished
    cam, sent = camera(source=str(photos / "chelsea.png"), width=90, height=60)
    cam.execute()
    cam.execute()
    assert [m.data.shape for m in sent] == [(60, 90, 3)] and cam.finished


def test_a_folder_without_images_is_a_system_failure_naming_it(tmp_path: Path) -> None:
    cam, sent = camera(source=str(tmp_path), retry_s=0.01)
    cam.execute()
    assert cam.health_status == HealthStatus.SYSTEM_FAILURE and sent == []
    assert f"image folder {str(tmp_path)!r} holds no images (png, jpg, jpeg, bmp, ...)" in cam.health.text


PHOTO_SYSTEM = """
from embagents.components import Camera, CameraConfig, Component
from embagents.msgs import Image
from embagents.system import System
from embagents.topic import Topic

image = Topic("image", Image)


class Shapes(Component):
    allowed_inputs = {{"Required": [Image]}}

    def on_activate(self):
        self.seen = []

    def shapes(self):
        return list(self.seen)

    def _execution_step(self, **inputs):
        self.seen.append(list(inputs["image"].data.shape))


cam = Camera(name="cam", outputs=[image], config=CameraConfig(source={source!r}, loop=True), trigger=20.0)
shapes = Shapes(name="shapes", inputs=[image], trigger=image)
system = System([cam, shapes])
"""


def test_photos_play_as_a_camera_in_a_real_run(photos: Path, tmp_path: Path) -> None:
    from actors import ActorSystem
    from embagents.requests import Call
    from embagents.runtime.component_actor import ComponentActor
    from embagents.system import load_system, remember_system
    from tests.helpers import wait_until

    path = tmp_path / "system.py"
    path.write_text(PHOTO_SYSTEM.format(source=str(photos / "*.png")))
    remember_system(str(path), load_system(str(path)))
    with ActorSystem() as asys:
        asys.spawn(ComponentActor, "shapes", str(path), "shapes")
        asys.spawn(ComponentActor, "cam", str(path), "cam")
        got = wait_until(lambda: (s := asys.ref("shapes").ask(Call("shapes"), timeout=5).get()) and len(s) >= 4 and s)
    assert {tuple(s) for s in got} == {(512, 512, 3), (300, 451, 3)}  # both photos, through shared memory
