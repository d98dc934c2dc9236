"""The one ONNX graph builder of the converters: unique node names, weights as initializers, the layers
transformer encoders share (linear, layer norm, exact GELU, multi-head attention).

The Whisper and BERT converters write their graphs with it. ``onnx`` is imported when a graph is made
(it is heavy, and only model preparation needs it).

Example::

    >>> import numpy as np
    >>> g = Graph()
    >>> y = g.linear("x", np.eye(2, dtype=np.float32), np.zeros(2, np.float32))
    >>> [n.op_type for n in g.nodes], len(g.inits)
    (['MatMul', 'Add'], 2)
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["Graph"]


class Graph:
    """Nodes and initializers of a graph being written (names are made unique here)."""

    def __init__(self) -> None:
        import onnx.helper  # heavy: only a conversion needs it
        import onnx.numpy_helper

        self.h, self.nh = onnx.helper, onnx.numpy_helper
        self.nodes: list[Any] = []
        self.inits: list[Any] = []
        self.n = 0

    def const(self, value: Any, name: str | None = None) -> str:
        """An initializer holding ``value``; its name."""
        self.n += 1
        name = name or f"c{self.n}"
        self.inits.append(self.nh.from_array(np.asarray(value), name))
        return name

    def op(self, kind: str, *inputs: str, outputs: int = 1, name: str | None = None, **attrs: Any) -> Any:
        """A node of type ``kind``; its output name (a list of them when ``outputs`` > 1)."""
        self.n += 1
        outs = [name] if name and outputs == 1 else [f"{kind.lower()}{self.n}_{i}" for i in range(outputs)]
        self.nodes.append(self.h.make_node(kind, list(inputs), outs, **attrs))
        return outs[0] if outputs == 1 else outs

    def linear(self, x: str, w: np.ndarray, b: np.ndarray | None = None) -> str:
        """``x @ w.T + b`` (``w`` as PyTorch stores it: out x in)."""
        y = self.op("MatMul", x, self.const(np.ascontiguousarray(w.T)))
        return y if b is None else self.op("Add", y, self.const(b))

    def layer_norm(self, x: str, gamma: np.ndarray, beta: np.ndarray, eps: float = 1e-5) -> str:
        return self.op("LayerNormalization", x, self.const(gamma), self.const(beta), axis=-1, epsilon=eps)

    def gelu(self, x: str) -> str:
        """Exact (erf) GELU, as Whisper's and BERT's; opset 17 has no Gelu op."""
        erf = self.op("Erf", self.op("Div", x, self.const(np.float32(np.sqrt(2.0)))))
        return self.op("Mul", self.op("Mul", x, self.const(np.float32(0.5))),
                       self.op("Add", erf, self.const(np.float32(1.0))))

    def attention(self, q: str, k: str, v: str, heads: int, dim: int, mask: str | None = None) -> str:
        """Multi-head attention of (N, Tq, D) queries over (N, Tk, D) keys/values; ``mask`` is added to the scores."""
        split = self.const(np.array([0, 0, heads, dim // heads], np.int64))
        qh = self.op("Transpose", self.op("Reshape", q, split), perm=[0, 2, 1, 3])
        kh = self.op("Transpose", self.op("Reshape", k, split), perm=[0, 2, 3, 1])
        vh = self.op("Transpose", self.op("Reshape", v, split), perm=[0, 2, 1, 3])
        qk = self.op("Mul", self.op("MatMul", qh, kh), self.const(np.float32((dim // heads) ** -0.5)))
        if mask is not None:
            qk = self.op("Add", qk, mask)
        out = self.op("MatMul", self.op("Softmax", qk, axis=-1), vh)
        return self.op("Reshape", self.op("Transpose", out, perm=[0, 2, 1, 3]),
                       self.const(np.array([0, 0, dim], np.int64)))

    def model(self, name: str, inputs: list[Any], outputs: list[Any], metadata: dict[str, Any], *, opset: int) -> Any:
        """The ONNX model of the graph, with ``metadata`` as its properties."""
        graph = self.h.make_graph(self.nodes, name, inputs, outputs, self.inits)
        model = self.h.make_model(graph, opset_imports=[self.h.make_opsetid("", opset)], producer_name="embagents")
        model.ir_version = 8  # loadable by the onnxruntime sherpa-onnx bundles, not only the newest
        self.h.set_model_props(model, {k: str(v) for k, v in metadata.items()})
        return model
