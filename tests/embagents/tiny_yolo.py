"""A tiny YOLO-shaped ONNX detector, built with the ``onnx`` helper API (a few KB).

Input ``images`` (B, 3, 64, 64) float32 with a dynamic batch; output
``output0`` in the v8/v11 layout (B, 4 + 2 classes, 3 anchors) or the v5
layout (B, 3 anchors, 5 + 2). Its predictions do not depend on the pixels
(they are constants added to 0 x the image mean): anchor 0 is a 'robot' box
centred at (32, 32), 20 x 20, score 0.9; anchor 1 the same box shifted by
one pixel, score 0.8 (NMS removes it); anchor 2 a 'cup' below any threshold.
The metadata ``names`` is what an Ultralytics export writes.

Example::

    >>> path = make_tiny_yolo("/tmp/tiny.onnx")          # doctest: +SKIP
"""

from __future__ import annotations

import numpy as np

SIZE = 64
NAMES = {0: "robot", 1: "cup"}
# cx, cy, w, h, robot, cup per anchor
ANCHORS = np.array([[32, 32, 20, 20, 0.9, 0.0], [33, 33, 20, 20, 0.8, 0.0], [10, 10, 4, 4, 0.0, 0.05]], np.float32)


def make_tiny_yolo(path: str, layout: str = "v8") -> str:
    """Write the model (``layout`` "v8", "v5", or "bad": a (B, 7) output no detector reads)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    if layout == "v8":
        pred = ANCHORS.T[None]  # (1, 6, 3)
    elif layout == "v5":
        pred = np.concatenate([ANCHORS[:, :4], np.ones((3, 1), np.float32), ANCHORS[:, 4:]], 1)[None]  # (1, 3, 7)
    else:
        pred = np.zeros((1, 7), np.float32)
    nodes = [
        helper.make_node("ReduceMean", ["images", "axes"], ["mean"], keepdims=1),
        helper.make_node("Mul", ["mean", "zero"], ["zeros"]),
        helper.make_node("Reshape", ["zeros", "shape"], ["zeros_r"]),
        helper.make_node("Add", ["zeros_r", "pred"], ["output0"]),
    ]
    shape = [-1, 1, 1] if pred.ndim == 3 else [-1, 1]
    inits = [numpy_helper.from_array(np.array([1, 2, 3], np.int64), "axes"),
             numpy_helper.from_array(np.array(0.0, np.float32), "zero"),
             numpy_helper.from_array(np.array(shape, np.int64), "shape"),
             numpy_helper.from_array(pred, "pred")]
    out_shape = ["batch", *pred.shape[1:]]
    graph = helper.make_graph(
        nodes, "tiny_yolo",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, ["batch", 3, SIZE, SIZE])],
        [helper.make_tensor_value_info("output0", TensorProto.FLOAT, out_shape)], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 9
    helper.set_model_props(model, {"names": repr(NAMES)})
    onnx.checker.check_model(model)
    onnx.save(model, path)
    return path
