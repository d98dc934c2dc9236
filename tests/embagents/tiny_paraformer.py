"""A few-KB Paraformer model directory sherpa-onnx loads: it hears "hello robot" in any audio.

sherpa-onnx's offline Paraformer reads ``model.onnx`` (inputs ``speech`` (N, T, 560)
LFR features and ``speech_lengths``; outputs ``logits`` (N, U, vocab) and
``token_num``; metadata ``vocab_size``, ``lfr_window_size``, ``lfr_window_shift``,
``neg_mean``, ``inv_stddev``) and ``tokens.txt``. This one's logits are a
constant whose greedy path is ``hello robot </s>``: every code path of a
non-Whisper model directory is real (load, features, decode, tokens), the
words are fixed.
"""

from __future__ import annotations

import os

import numpy as np

TOKENS = ["<blank>", "<s>", "</s>", "hello", "robot"]
SAID = "hello robot"


def make_tiny_paraformer(folder: str) -> str:
    import onnx
    from onnx import TensorProto as T
    from onnx import helper as h
    from onnx import numpy_helper as nh

    path = [3, 4, 2, 2]  # hello robot </s>
    logits = np.full((1, len(path), len(TOKENS)), -5.0, np.float32)
    logits[0, np.arange(len(path)), path] = 5.0
    consts = {"L": logits, "zero": np.array([0], np.int64), "one": np.array([1], np.int64),
              "rest": np.array([len(path), len(TOKENS)], np.int64)}
    nodes = [
        h.make_node("Shape", ["speech"], ["shape"]),
        h.make_node("Slice", ["shape", "zero", "one"], ["n"]),
        h.make_node("Concat", ["n", "rest"], ["full"], axis=0),
        h.make_node("Expand", ["L", "full"], ["logits"]),  # one row of logits per utterance in the batch
        h.make_node("Identity", ["speech_lengths"], ["token_num"]),
    ]
    graph = h.make_graph(
        nodes, "tiny_paraformer",
        [h.make_tensor_value_info("speech", T.FLOAT, ["N", "T", 560]),
         h.make_tensor_value_info("speech_lengths", T.INT32, ["N"])],
        [h.make_tensor_value_info("logits", T.FLOAT, ["N", len(path), len(TOKENS)]),
         h.make_tensor_value_info("token_num", T.INT32, ["N"])],
        [nh.from_array(v, k) for k, v in consts.items()])
    model = h.make_model(graph, opset_imports=[h.make_opsetid("", 17)])
    model.ir_version = 8
    h.set_model_props(model, {"vocab_size": str(len(TOKENS)), "lfr_window_size": "7", "lfr_window_shift": "6",
                              "neg_mean": ",".join(["0"] * 560), "inv_stddev": ",".join(["1"] * 560)})
    os.makedirs(folder, exist_ok=True)
    onnx.save(model, os.path.join(folder, "model.onnx"))
    with open(os.path.join(folder, "tokens.txt"), "w") as f:
        f.writelines(f"{s} {i}\n" for i, s in enumerate(TOKENS))
    return folder
