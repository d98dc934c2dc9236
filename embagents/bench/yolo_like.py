"""A YOLOv8-layout ONNX detector of random weights, for throughput measurements (``onnx`` helper API).

Four convolutions (3 -> 16 -> 32 -> 64 channels, stride 2 each, then 1 x 1 to
4 + 80 outputs) on a (B, 3, 320, 320) input with a dynamic batch: about 80
million multiply-adds per image, a cost between a toy and a real YOLOv8n (8.7
billion at 640). Its scores sit near 0.5, so with a threshold of 0.9 it finds
nothing: it measures serving, not detection.

Example::

    >>> path = write_yolo_like("/tmp/yolo_like.onnx")     # doctest: +SKIP
"""

from __future__ import annotations

import numpy as np

__all__ = ["write_yolo_like"]


def write_yolo_like(path: str, size: int = 320, classes: int = 80) -> str:
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(0)
    chans = [3, 16, 32, 64]
    nodes, inits, x = [], [], "images"
    for i, (cin, cout) in enumerate(zip(chans, chans[1:], strict=False)):
        w = (rng.standard_normal((cout, cin, 3, 3)) * 0.1).astype(np.float32)
        inits.append(numpy_helper.from_array(w, f"w{i}"))
        nodes += [helper.make_node("Conv", [x, f"w{i}"], [f"c{i}"], strides=[2, 2], pads=[1, 1, 1, 1]),
                  helper.make_node("Relu", [f"c{i}"], [f"r{i}"])]
        x = f"r{i}"
    head = (rng.standard_normal((4 + classes, chans[-1], 1, 1)) * 0.01).astype(np.float32)
    cells = (size // 8) ** 2
    inits += [numpy_helper.from_array(head, "head"),
              numpy_helper.from_array(np.array([0, 4 + classes, cells], np.int64), "shape")]
    nodes += [helper.make_node("Conv", [x, "head"], ["h"]),
              helper.make_node("Reshape", ["h", "shape"], ["hr"]),
              helper.make_node("Sigmoid", ["hr"], ["output0"])]
    graph = helper.make_graph(
        nodes, "yolo_like", [helper.make_tensor_value_info("images", TensorProto.FLOAT, ["batch", 3, size, size])],
        [helper.make_tensor_value_info("output0", TensorProto.FLOAT, ["batch", 4 + classes, cells])], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 9
    onnx.checker.check_model(model)
    onnx.save(model, path)
    return path
