"""Boxes in a vision-language model's answer: the formats real VLMs answer grounding requests in.

:func:`parse_boxes` reads, in this order:

- Qwen2.5-VL JSON: ``[{"bbox_2d": [x1, y1, x2, y2], "label": "cup"}]`` in pixels
  (also ``"bbox"`` / ``"box"`` keys, inside a Markdown ``json`` code fence or not);
- Qwen2-VL tokens: ``<|object_ref_start|>cup<|object_ref_end|><|box_start|>(x1,y1),(x2,y2)<|box_end|>``,
  coordinates in 0..1000;
- PaliGemma: ``<loc0256><loc0128><loc0768><loc0512> cup`` (y1, x1, y2, x2 in 0..1023 bins);
- Florence-2: ``cup<loc_100><loc_200><loc_300><loc_400>`` (x1, y1, x2, y2 in 0..999 bins);
- a plain list, as LLaVA and moondream answer: ``cup: [0.12, 0.34, 0.56, 0.78]``, normalised
  when every number is at most 1, else pixels.

Boxes come back as x1, y1, x2, y2 pixels of the image, clipped to it and ordered.

Example::

    >>> boxes, labels = parse_boxes("The cup is at [0.25, 0.5, 0.75, 1.0].", 200, 100, default_label="cup")
    >>> boxes.tolist(), labels
    ([[50.0, 50.0, 150.0, 100.0]], ['cup'])
"""

from __future__ import annotations

import json
import re
from typing import Any

import numpy as np

__all__ = ["parse_boxes"]

_NUM = r"-?\d+(?:\.\d+)?"
_QWEN2 = re.compile(r"(?:<\|object_ref_start\|>(.*?)<\|object_ref_end\|>)?\s*<\|box_start\|>\s*\(\s*(" + _NUM
                    + r")\s*,\s*(" + _NUM + r")\s*\)\s*,\s*\(\s*(" + _NUM + r")\s*,\s*(" + _NUM + r")\s*\)\s*<\|box_end\|>")
_PALIGEMMA = re.compile(r"((?:<loc\d{4}>){4})\s*([^<;\n]*)")
_FLORENCE = re.compile(r"([^<>]*?)((?:<loc_\d{1,4}>){4})")
_LIST = re.compile(r"([A-Za-z][\w \-]*?)?\s*[:=]?\s*[\[(]\s*(" + _NUM + r")\s*,\s*(" + _NUM + r")\s*,\s*("
                   + _NUM + r")\s*,\s*(" + _NUM + r")\s*[\])]")
_FENCE = re.compile(r"```(?:json)?\s*(.*?)```", re.DOTALL)
_BOX_KEYS = ("bbox_2d", "bbox", "box", "box_2d")


def _json_boxes(text: str) -> list[tuple[list[float], str | None]]:
    fenced = _FENCE.search(text)
    body = fenced.group(1) if fenced else text
    start = min((i for i in (body.find("["), body.find("{")) if i >= 0), default=-1)
    if start < 0:
        return []
    try:
        value: Any = json.JSONDecoder().raw_decode(body[start:])[0]
    except ValueError:
        return []
    items = value if isinstance(value, list) else [value]
    out = []
    for item in items:
        if not isinstance(item, dict):
            continue
        box = next((item[k] for k in _BOX_KEYS if k in item), None)
        if isinstance(box, list) and len(box) == 4 and all(isinstance(v, (int, float)) for v in box):
            label = item.get("label") or item.get("name")
            out.append(([float(v) for v in box], str(label) if label else None))
    return out


def parse_boxes(text: str, width: int, height: int, *, default_label: str = "object") -> tuple[np.ndarray, list[str]]:
    """Every box in ``text`` as ((N, 4) float32 x1 y1 x2 y2 pixels, labels); none found: N is 0.

    >>> parse_boxes("<loc0000><loc0256><loc0512><loc0768> cat", 100, 100)[0].tolist()
    [[25.0, 0.0, 75.0, 50.0]]
    """
    found: list[tuple[float, float, float, float, str]] = []
    for box, label in _json_boxes(text):
        found.append((*box, label or default_label))  # type: ignore[arg-type]
    if not found:
        for m in _QWEN2.finditer(text):
            x1, y1, x2, y2 = (float(v) / 1000.0 for v in m.groups()[1:])
            found.append((x1 * width, y1 * height, x2 * width, y2 * height, (m.group(1) or default_label).strip()))
    if not found:
        for m in _PALIGEMMA.finditer(text):
            y1, x1, y2, x2 = (int(v) / 1024.0 for v in re.findall(r"\d{4}", m.group(1)))
            label = m.group(2).strip() or default_label
            found.append((x1 * width, y1 * height, x2 * width, y2 * height, label))
    if not found:
        for m in _FLORENCE.finditer(text):
            x1, y1, x2, y2 = (int(v) / 1000.0 for v in re.findall(r"\d+", m.group(2)))
            found.append((x1 * width, y1 * height, x2 * width, y2 * height, m.group(1).strip() or default_label))
    if not found:
        for m in _LIST.finditer(text):
            nums = [float(v) for v in m.groups()[1:]]
            if all(0.0 <= v <= 1.0 for v in nums):
                nums = [nums[0] * width, nums[1] * height, nums[2] * width, nums[3] * height]
            label = (m.group(1) or "").strip()
            words = label.split()
            # "The cup is at [..]" names its object first; "cup: [..]" is the label itself.
            if len(words) > 1 and words[0].lower() in ("the", "a", "an"):
                label = words[1]
            elif len(words) > 3:
                label = words[-1]
            found.append((*nums, label if label and label.lower() not in ("at", "is", "box") else default_label))  # type: ignore[arg-type]
    if not found:
        return np.zeros((0, 4), np.float32), []
    boxes = np.array([f[:4] for f in found], np.float32)
    boxes = np.concatenate([np.minimum(boxes[:, :2], boxes[:, 2:]), np.maximum(boxes[:, :2], boxes[:, 2:])], axis=1)
    boxes[:, [0, 2]] = boxes[:, [0, 2]].clip(0, width)
    boxes[:, [1, 3]] = boxes[:, [1, 3]].clip(0, height)
    return boxes, [str(f[4]) for f in found]
