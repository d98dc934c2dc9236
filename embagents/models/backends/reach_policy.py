"""A small real ONNX policy: a proportional controller toward a target pose, written with ``onnx``'s helper API.

For joint positions ``q`` the chunk's action ``k`` (0-based) is
``q + (1 - (1 - gain) ** (k + 1)) * (target - q)``: each step closes
``gain`` of the remaining error, as a P controller run ``k + 1`` times would.
With ``camera`` the graph also takes ``observation.images.<camera>`` (its
mean brightness enters the sum with weight 0: the image really travels to
onnxruntime, as a vision policy's would, without moving the arm).

Example::

    >>> import numpy as np, onnxruntime as ort
    >>> path = write_reach_policy("/tmp/reach_doc.onnx", target=[1.0, 0.0], gain=0.5, chunk=3)
    >>> ort.InferenceSession(path).run(None, {"observation.state": np.zeros((1, 2), np.float32)})[0][0].tolist()
    [[0.5, 0.0], [0.75, 0.0], [0.875, 0.0]]
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np

__all__ = ["write_reach_policy"]


def write_reach_policy(path: str, target: Sequence[float], gain: float = 0.1, chunk: int = 10,
                       camera: str | None = None, image_size: tuple[int, int] = (240, 320)) -> str:
    """Write the policy to ``path`` (atomically) and return it. ``image_size`` is (height, width)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    if not 0.0 < gain <= 1.0:
        raise ValueError(f"gain is the share of the error closed per step, in (0, 1]; got {gain!r}")
    n = len(target)
    weights = (1.0 - (1.0 - gain) ** np.arange(1, chunk + 1, dtype=np.float64)).astype(np.float32)
    inits = [
        numpy_helper.from_array(np.asarray(target, np.float32).reshape(1, 1, n), "target"),
        numpy_helper.from_array(weights.reshape(1, chunk, 1), "weights"),
        numpy_helper.from_array(np.array([1, 1, n], np.int64), "state_shape"),
    ]
    inputs = [helper.make_tensor_value_info("observation.state", TensorProto.FLOAT, [1, n])]
    nodes = [
        helper.make_node("Reshape", ["observation.state", "state_shape"], ["q"]),
        helper.make_node("Sub", ["target", "q"], ["error"]),
        helper.make_node("Mul", ["error", "weights"], ["steps"]),
        helper.make_node("Add", ["q", "steps"], ["moved"]),
    ]
    last = "moved"
    if camera:
        h, w = image_size
        inputs.append(helper.make_tensor_value_info(f"observation.images.{camera}", TensorProto.UINT8, [1, h, w, 3]))
        inits.append(numpy_helper.from_array(np.zeros(1, np.float32), "zero"))
        nodes += [
            helper.make_node("Cast", [f"observation.images.{camera}"], ["pixels"], to=TensorProto.FLOAT),
            helper.make_node("ReduceMean", ["pixels"], ["brightness"], keepdims=0),
            helper.make_node("Mul", ["brightness", "zero"], ["nothing"]),
            helper.make_node("Add", ["moved", "nothing"], ["with_image"]),
        ]
        last = "with_image"
    nodes.append(helper.make_node("Identity", [last], ["action"]))
    graph = helper.make_graph(nodes, "reach_policy", inputs,
                              [helper.make_tensor_value_info("action", TensorProto.FLOAT, [1, chunk, n])], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="embagents")
    model.ir_version = 8  # read by every onnxruntime >= 1.14
    onnx.checker.check_model(model)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    tmp = f"{path}.{os.getpid()}.part"
    onnx.save(model, tmp)
    os.replace(tmp, path)
    return path
