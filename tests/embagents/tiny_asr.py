"""Few-KB sherpa-onnx model directories (Paraformer, transducer, Moonshine) that hear "hello robot" in any audio.

They test a user's non-Whisper model end to end (no such model ships on PyPI):
every code path is real (load, features, decode, tokens), the words are fixed.

sherpa-onnx's offline Paraformer reads ``model.onnx`` (inputs ``speech`` (N, T, 560)
LFR features and ``speech_lengths``; outputs ``logits`` (N, U, vocab) and
``token_num``; metadata ``vocab_size``, ``lfr_window_size``, ``lfr_window_shift``,
``neg_mean``, ``inv_stddev``) and ``tokens.txt``: this one's logits are a
constant whose greedy path is ``hello robot </s>``. Its offline transducer
reads ``encoder.onnx`` (``x``, ``x_lens`` -> ``encoder_out``, ``encoder_out_lens``;
metadata ``model_type``), ``decoder.onnx`` (``y`` (N, context) -> ``decoder_out``;
metadata ``vocab_size``, ``context_size``) and ``joiner.onnx`` (-> ``logit``):
this one's joiner emits the token that follows the last one emitted
(blank -> hello -> robot -> blank). Its Moonshine reads ``preprocess.onnx``
(audio -> features), ``encode.onnx``, ``uncached_decode.onnx`` and
``cached_decode.onnx`` (token, encoder output, length, states -> logits,
states): this one's decoders score the token that follows the last one
(<s> -> hello -> robot -> </s>).
"""

from __future__ import annotations

import os
from typing import Any

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


def _save(folder: str, name: str, nodes: list[Any], inputs: list[Any], outputs: list[Any],
          consts: dict[str, np.ndarray], meta: dict[str, str]) -> None:
    import onnx
    from onnx import helper as h
    from onnx import numpy_helper as nh

    graph = h.make_graph(nodes, name, inputs, outputs, [nh.from_array(np.asarray(v), k) for k, v in consts.items()])
    model = h.make_model(graph, opset_imports=[h.make_opsetid("", 17)])
    model.ir_version = 8
    h.set_model_props(model, meta)
    onnx.save(model, os.path.join(folder, f"{name}.onnx"))


def make_tiny_transducer(folder: str) -> str:
    from onnx import TensorProto as T
    from onnx import helper as h

    v = len(TOKENS)
    os.makedirs(folder, exist_ok=True)
    _save(folder, "encoder",  # zeros, one frame per feature frame: the joiner ignores the audio
          [h.make_node("Slice", ["x", "s0", "s1", "axis"], ["xs"]), h.make_node("Mul", ["xs", "zero"], ["encoder_out"]),
           h.make_node("Identity", ["x_lens"], ["encoder_out_lens"])],
          [h.make_tensor_value_info("x", T.FLOAT, ["N", "T", 80]), h.make_tensor_value_info("x_lens", T.INT64, ["N"])],
          [h.make_tensor_value_info("encoder_out", T.FLOAT, ["N", "T", v]),
           h.make_tensor_value_info("encoder_out_lens", T.INT64, ["N"])],
          {"s0": np.array([0], np.int64), "s1": np.array([v], np.int64), "axis": np.array([2], np.int64),
           "zero": np.float32(0)}, {"model_type": "zipformer", "version": "1"})
    follows = np.zeros((v, v), np.float32)  # row: the last token emitted; column: the next one's score
    follows[[0, 1, 2, 3, 4], [3, 0, 0, 4, 0]] = 10.0  # blank -> hello -> robot -> blank
    _save(folder, "decoder",
          [h.make_node("Gather", ["y", "last"], ["y_last"], axis=1), h.make_node("Gather", ["follows", "y_last"], ["decoder_out"])],
          [h.make_tensor_value_info("y", T.INT64, ["N", 2])], [h.make_tensor_value_info("decoder_out", T.FLOAT, ["N", v])],
          {"last": np.int64(1), "follows": follows}, {"vocab_size": str(v), "context_size": "2"})
    _save(folder, "joiner",
          [h.make_node("Mul", ["encoder_out", "zero"], ["silent"]), h.make_node("Add", ["decoder_out", "silent"], ["logit"])],
          [h.make_tensor_value_info("encoder_out", T.FLOAT, ["N", v]),
           h.make_tensor_value_info("decoder_out", T.FLOAT, ["N", v])],
          [h.make_tensor_value_info("logit", T.FLOAT, ["N", v])], {"zero": np.float32(0)}, {})
    with open(os.path.join(folder, "tokens.txt"), "w") as f:
        f.writelines(f"{s} {i}\n" for i, s in enumerate(["<blk>", "<sos/eos>", "<unk>", "\u2581hello", "\u2581robot"]))
    return folder


def make_tiny_moonshine(folder: str) -> str:
    from onnx import TensorProto as T
    from onnx import helper as h

    v = len(TOKENS)
    os.makedirs(folder, exist_ok=True)
    _save(folder, "preprocess", [h.make_node("Unsqueeze", ["audio", "last_axis"], ["features"])],
          [h.make_tensor_value_info("audio", T.FLOAT, [1, "S"])],
          [h.make_tensor_value_info("features", T.FLOAT, [1, "S", 1])], {"last_axis": np.array([2], np.int64)}, {})
    _save(folder, "encode", [h.make_node("Identity", ["features"], ["encoder_out"])],
          [h.make_tensor_value_info("features", T.FLOAT, [1, "S", 1]),
           h.make_tensor_value_info("features_len", T.INT32, [1])],
          [h.make_tensor_value_info("encoder_out", T.FLOAT, [1, "S", 1])], {}, {})
    follows = np.full((v, v), -10.0, np.float32)  # row: the last token; column: the next one's score
    follows[[0, 1, 2, 3, 4], [2, 3, 2, 4, 2]] = 10.0  # <s> -> hello -> robot -> </s>
    inputs = [h.make_tensor_value_info("tokens", T.INT32, [1, 1]),
              h.make_tensor_value_info("encoder_out", T.FLOAT, [1, "S", 1]),
              h.make_tensor_value_info("seq_len", T.INT32, [1])]
    for name, state_in in (("uncached_decode", []), ("cached_decode", ["state"])):
        nodes = [h.make_node("Gather", ["follows", "tokens"], ["logits"]),
                 h.make_node("Cast", ["seq_len"], ["state_out"], to=T.FLOAT)]  # a state, as a real decoder's cache
        _save(folder, name, nodes, inputs + [h.make_tensor_value_info(n, T.FLOAT, [1]) for n in state_in],
              [h.make_tensor_value_info("logits", T.FLOAT, [1, 1, v]),
               h.make_tensor_value_info("state_out", T.FLOAT, [1])], {"follows": follows}, {})
    with open(os.path.join(folder, "tokens.txt"), "w") as f:
        f.writelines(f"{s} {i}\n" for i, s in enumerate(["<unk>", "<s>", "</s>", "\u2581hello", "\u2581robot"]))
    return folder
