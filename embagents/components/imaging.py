"""Images for the vision components: any Image / CompressedImage as RGB, boxes drawn on a copy.

Example::

    >>> import numpy as np
    >>> from embagents.msgs import Image
    >>> image_rgb(Image(data=np.zeros((2, 3, 3), np.uint8), encoding="bgr8")).shape
    (2, 3, 3)
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from embagents.msgs import CompressedImage, Image

__all__ = ["annotate", "image_rgb"]

_TO_RGB = {"bgr8": "COLOR_BGR2RGB", "rgba8": "COLOR_RGBA2RGB", "bgra8": "COLOR_BGRA2RGB", "mono8": "COLOR_GRAY2RGB"}


def image_rgb(msg: Image | CompressedImage) -> np.ndarray:
    """The (H, W, 3) uint8 RGB pixels of ``msg``; ``ValueError`` naming what it got and what fits."""
    import cv2

    if isinstance(msg, CompressedImage):
        bgr = cv2.imdecode(np.frombuffer(msg.data, np.uint8), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError(f"CompressedImage ({msg.format}, {len(msg.data)} bytes) does not decode as an image; "
                             "send jpeg or png bytes")
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    data = msg.data
    if data.dtype != np.uint8:
        raise ValueError(f"Image data must be uint8, got {data.dtype} (shape {data.shape}); "
                         "scale it (e.g. (img * 255).astype(np.uint8))")
    if msg.encoding == "rgb8" and data.ndim == 3 and data.shape[2] == 3:
        return data
    conv = _TO_RGB.get(msg.encoding)
    channels = 1 if data.ndim == 2 else data.shape[2] if data.ndim == 3 else -1
    want = {"mono8": 1, "rgba8": 4, "bgra8": 4}.get(msg.encoding, 3)
    if conv is None or channels != want:
        raise ValueError(f"Image of encoding {msg.encoding!r} and shape {data.shape} is not one this reads: "
                         "send rgb8/bgr8 (H, W, 3), rgba8/bgra8 (H, W, 4) or mono8 (H, W)")
    return cv2.cvtColor(data, getattr(cv2, conv))


def annotate(rgb: np.ndarray, boxes: np.ndarray, labels: Sequence[str], scores: Sequence[float] | np.ndarray,
             ids: Sequence[Any] | None = None) -> np.ndarray:
    """A copy of ``rgb`` with each box, its label and score (and track id) drawn."""
    import cv2

    out = np.ascontiguousarray(rgb).copy()
    thick = max(1, round(min(out.shape[:2]) / 300))
    for i, (box, label, score) in enumerate(zip(boxes, labels, scores, strict=True)):
        x1, y1, x2, y2 = (int(v) for v in box)
        text = f"{label} {float(score):.2f}" + (f" #{ids[i]}" if ids is not None else "")
        cv2.rectangle(out, (x1, y1), (x2, y2), (255, 64, 0), 2 * thick)
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.5 * thick, thick)
        top = max(y1 - th - 6, 0)
        cv2.rectangle(out, (x1, top), (x1 + tw + 4, top + th + 6), (255, 64, 0), -1)
        cv2.putText(out, text, (x1 + 2, top + th + 2), cv2.FONT_HERSHEY_SIMPLEX, 0.5 * thick, (255, 255, 255), thick)
    return out
