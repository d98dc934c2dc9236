"""A tiny ONNX policy (built with the onnx helper API) for the LeRobot protocol tests.

``observation.state`` (1, N) float32 in; a chunk (1, T, N) out: T steps of a
proportional move toward a fixed target, ``state + gain * (target - state) * k``
for k = 1..T. Real onnxruntime inference, a meaningful answer.
"""

from __future__ import annotations

import os

import numpy as np

__all__ = ["expected_chunk", "make_tiny_policy"]


def expected_chunk(state: np.ndarray, target: np.ndarray, chunk: int, gain: float = 0.2) -> np.ndarray:
    """What the policy answers for ``state`` (the same arithmetic in numpy)."""
    steps = np.arange(1, chunk + 1, dtype=np.float32)[:, None]
    return (state[None, :] + gain * steps * (target - state)[None, :]).astype(np.float32)


def make_tiny_policy(path: str, target: np.ndarray, chunk: int, gain: float = 0.2) -> str:
    """Write the policy for joints ``len(target)`` and ``chunk`` steps; cached at ``path``."""
    if os.path.isfile(path):
        return path
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    n = len(target)
    consts = [
        numpy_helper.from_array(np.asarray(target, np.float32).reshape(1, 1, n), "target"),
        numpy_helper.from_array((gain * np.arange(1, chunk + 1, dtype=np.float32)).reshape(1, chunk, 1), "steps"),
        numpy_helper.from_array(np.array([1], np.int64), "axis1"),
    ]
    nodes = [
        helper.make_node("Unsqueeze", ["observation.state", "axis1"], ["state3"]),  # (1, 1, N)
        helper.make_node("Sub", ["target", "state3"], ["error"]),
        helper.make_node("Mul", ["steps", "error"], ["move"]),  # (1, T, N)
        helper.make_node("Add", ["state3", "move"], ["actions"]),
    ]
    graph = helper.make_graph(
        nodes, "tiny_reach",
        [helper.make_tensor_value_info("observation.state", TensorProto.FLOAT, [1, n])],
        [helper.make_tensor_value_info("actions", TensorProto.FLOAT, [1, chunk, n])],
        initializer=consts,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    tmp = f"{path}.{os.getpid()}.tmp"
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    onnx.save(model, tmp)
    os.replace(tmp, path)
    return path
