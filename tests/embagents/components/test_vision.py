"""The Vision component against a real detector model actor (the tiny generated YOLO)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")
pytest.importorskip("onnxruntime")
pytest.importorskip("supervision")

from actors import ActorSystem  # noqa: E402
from embagents.components import HealthStatus, Vision, VisionConfig  # noqa: E402
from embagents.models import LocalModelClient  # noqa: E402
from embagents.models.actor import ModelActor  # noqa: E402
from embagents.msgs import CompressedImage, Detections, Image, Trackings  # noqa: E402
from embagents.topic import Topic  # noqa: E402

camera = Topic("camera", Image)


@pytest.fixture(scope="module")
def detector(tiny_yolo: str) -> Iterator[str]:
    with ActorSystem() as asys:
        asys.spawn(ModelActor, "det", "detector", tiny_yolo, {"family": "yolo"}, True, wait=60)
        yield "det"


def vision(detector: str, tmp_path: Path, inputs: Any = (camera,), **config: Any) -> tuple[Vision, list[Any]]:
    outputs = [Topic("found", Detections), Topic("tracks", Trackings), Topic("drawn", Image)]
    comp = Vision(name="vision", inputs=list(inputs), outputs=outputs, model_client=LocalModelClient(detector),
                  config=VisionConfig(media_dir=str(tmp_path), **config))
    sent: list[Any] = []
    comp.attach(lambda topic, msg: sent.append(msg))
    return comp, sent


def step(comp: Vision, msg: Any, topic: str = "camera") -> bool:
    return comp.on_message(topic, msg) and comp.execute()


def test_an_image_gives_detections_with_the_image_size(detector: str, tmp_path: Path) -> None:
    comp, sent = vision(detector, tmp_path)
    assert step(comp, Image(data=np.zeros((128, 256, 3), np.uint8), frame_id="cam0", stamp=5.0))
    (det,) = sent
    assert isinstance(det, Detections) and det.labels == ["robot"] and det.frame_id == "cam0" and det.stamp == 5.0
    assert (det.image_width, det.image_height) == (256, 128)
    assert det.boxes.tolist() == [[88.0, 24.0, 168.0, 104.0]]  # x 4 (256 / 64), 32 px of padding off


def test_tracking_keeps_one_id_and_visualization_draws_the_box(detector: str, tmp_path: Path) -> None:
    comp, sent = vision(detector, tmp_path, enable_visualization=True)
    assert comp.track("robot") == ["robot"]
    for _ in range(3):
        assert step(comp, Image(data=np.zeros((64, 64, 3), np.uint8)))
    tracks = [m for m in sent if isinstance(m, Trackings)]
    drawn = [m for m in sent if isinstance(m, Image)]
    assert len(tracks) == 3 and [t.track_ids.tolist() for t in tracks] == [tracks[0].track_ids.tolist()] * 3
    assert len(tracks[0].track_ids) == 1 and tracks[0].labels == ["robot"]
    assert drawn[0].data[22, 30].tolist() != [0, 0, 0] and drawn[0].data[32, 32].tolist() == [0, 0, 0]  # edge, not inside


def test_take_picture_and_record_video_write_files_opencv_reads(detector: str, tmp_path: Path) -> None:
    comp, _ = vision(detector, tmp_path)
    with pytest.raises(RuntimeError, match="no frame yet"):
        comp.take_picture()
    frame = np.zeros((64, 96, 3), np.uint8)
    frame[..., 0] = 200  # red
    step(comp, Image(data=frame))
    picture = cv2.imread(comp.take_picture())
    assert picture.shape == (64, 96, 3) and picture[5, 5].tolist() == [0, 0, 200]  # BGR on disk
    video = comp.record_video(10.0)
    for _ in range(5):
        step(comp, Image(data=frame))
    comp.on_shutdown()
    cap = cv2.VideoCapture(video)
    count = 0
    while cap.read()[0]:
        count += 1
    assert video.endswith(".mp4") and count == 5


def test_a_compressed_image_is_decoded(detector: str, tmp_path: Path) -> None:
    comp, sent = vision(detector, tmp_path, inputs=[Topic("jpeg", CompressedImage)])
    ok, jpeg = cv2.imencode(".jpg", np.zeros((64, 64, 3), np.uint8))
    assert step(comp, CompressedImage(data=jpeg.tobytes(), format="jpeg"), "jpeg")
    assert sent[0].labels == ["robot"]


def test_an_image_of_the_wrong_shape_or_dtype_is_a_clear_algorithm_failure(detector: str, tmp_path: Path) -> None:
    comp, sent = vision(detector, tmp_path)
    assert not step(comp, Image(data=np.zeros((64, 64, 3), np.float32)))
    assert comp.health.status == HealthStatus.ALGORITHM_FAILURE
    assert "must be uint8, got float32" in comp.health.text and "astype(np.uint8)" in comp.health.text
    assert not step(comp, Image(data=np.zeros((64, 64, 2), np.uint8)))
    assert "not one this reads: send rgb8/bgr8 (H, W, 3)" in comp.health.text
    assert step(comp, Image(data=np.zeros((64, 64, 3), np.uint8))) and sent[-1].labels == ["robot"]


def test_a_client_that_cannot_detect_is_a_declaration_error() -> None:
    from embagents.components import ComponentError

    class Chatty:
        name = "chatty"

        def chat(self, messages: list, **options: Any) -> str:
            return "hi"

    with pytest.raises(ComponentError, match="model client 'chatty' cannot detect"):
        Vision(name="vision", inputs=[camera], outputs=[Topic("found", Detections)], model_client=Chatty())
