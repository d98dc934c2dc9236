"""Detectors on real onnxruntime sessions: the tiny generated YOLO and the real MTCNN files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("onnxruntime")
pytest.importorskip("cv2")

from embagents.models.backends.detectors import DetectorLayoutError, make_detector  # noqa: E402
from embagents.models.backends.onnx import OnnxSession  # noqa: E402
from tests.embagents.fixtures.tiny_yolo import make_tiny_yolo  # noqa: E402


def test_yolo_v8_boxes_map_back_through_the_letterbox_and_nms_drops_the_duplicate(tiny_yolo: str) -> None:
    det = make_detector(tiny_yolo, family="yolo")
    square, wide = det.detect_batch([np.zeros((128, 128, 3), np.uint8), np.zeros((64, 128, 3), np.uint8)])
    assert det.layout == "v8" and det.names == ["robot", "cup"]  # names from the export's metadata
    assert square["labels"] == ["robot"] and square["scores"].tolist() == pytest.approx([0.9])
    assert square["boxes"].tolist() == [[44.0, 44.0, 84.0, 84.0]]  # 64 px input -> 128 px image
    assert wide["boxes"].tolist() == [[44.0, 12.0, 84.0, 52.0]]  # 16 px of vertical padding removed


def test_yolo_v5_layout_and_class_names_from_a_list(tmp_path: Path) -> None:
    det = make_detector(make_tiny_yolo(str(tmp_path / "v5.onnx"), "v5"), family="yolo", class_names=["bot", "mug"])
    out = det.detect_batch([np.zeros((64, 64, 3), np.uint8)], threshold=0.01)[0]
    assert det.layout == "v5"
    assert out["labels"] == ["bot", "mug"]  # the 0.05 cup shows with a low threshold


def test_an_onnx_file_of_no_known_layout_says_what_it_found_and_expects(tmp_path: Path) -> None:
    with pytest.raises(DetectorLayoutError) as err:
        make_detector(make_tiny_yolo(str(tmp_path / "bad.onnx"), "bad"), family="yolo")
    text = str(err.value)
    assert "('output0', ['batch', 7])" in text and "v8/v11 (B, 4 + classes, anchors)" in text


def test_a_missing_model_file_names_the_path_and_how_to_get_one(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError) as err:
        OnnxSession(str(tmp_path / "nope.onnx"))
    assert str(tmp_path / "nope.onnx") in str(err.value) and "yolo export" in str(err.value)
    with pytest.raises(FileNotFoundError, match="pnet.onnx"):
        make_detector(str(tmp_path), family="mtcnn")


def test_mtcnn_finds_the_astronauts_face() -> None:
    skimage_data = pytest.importorskip("skimage.data")
    from embagents.models.files.hub import mtcnn_dir

    out = make_detector(mtcnn_dir(), family="mtcnn", threshold=0.9).detect_batch([skimage_data.astronaut()])[0]
    assert out["labels"] == ["face"] and out["scores"][0] > 0.99
    x1, y1, x2, y2 = out["boxes"][0]
    assert 150 < x1 < 200 and 40 < y1 < 80 and 240 < x2 < 290 and 150 < y2 < 200  # Eileen Collins' face
    empty = make_detector(mtcnn_dir(), family="mtcnn").detect_batch([np.zeros((120, 160, 3), np.uint8)])[0]
    assert empty["labels"] == [] and empty["boxes"].shape == (0, 4)
