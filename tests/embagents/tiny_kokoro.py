"""A tiny Kokoro-shaped voice folder for sherpa-onnx, built with the ``onnx`` helper API (a few KB + 1 MB of styles).

No Kokoro release can be had on these machines, so the tests make one of
its shape: ``model.onnx`` takes what sherpa-onnx's Kokoro runner feeds a
real one (``tokens`` int64 (1, n), a ``style`` (1, 256) row of ``voices.bin``
chosen by speaker and length, ``speed`` (1,)) and returns ``240 * n``
samples of a sine of the token ids; its metadata is what sherpa-onnx's
``scripts/kokoro/add-meta-data.py`` writes (24 kHz, 2 speakers, style_dim
510,1,256). ``tokens.txt`` maps the IPA symbols espeak-ng writes for English.

Example::

    >>> folder = make_tiny_kokoro("/tmp/kokoro")          # doctest: +SKIP
"""

from __future__ import annotations

import os

import numpy as np

SAMPLES_PER_TOKEN = 240
SPEAKERS = 2
SYMBOLS = sorted(set("$;:,.!?¡¿—…\"«»“” ()ˈˌːaæɑɒɔəɛɜɪʊʌbdðfɡhijklmnŋoprsʃtθuvwzʒᵻɐɾʔeɚɹɝʤʧ"))


def make_tiny_kokoro(folder: str) -> str:
    """Write ``model.onnx``, ``voices.bin`` and ``tokens.txt`` into ``folder``; return it."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    const = {"axis": np.array([2], np.int64), "per_token": np.array([1, 1, SAMPLES_PER_TOKEN], np.int64),
             "flat": np.array([-1], np.int64), "zero": np.array(0.0, np.float32), "half": np.array(0.5, np.float32)}
    nodes = [
        helper.make_node("Cast", ["tokens"], ["ids"], to=TensorProto.FLOAT),
        helper.make_node("Unsqueeze", ["ids", "axis"], ["ids3"]),
        helper.make_node("Expand", ["ids3", "per_token"], ["wide"]),
        helper.make_node("Reshape", ["wide", "flat"], ["row"]),
        helper.make_node("Sin", ["row"], ["wave"]),
        # style and speed are read (as a real model reads them) and weigh nothing
        helper.make_node("ReduceMean", ["style"], ["style_mean"], keepdims=0),
        helper.make_node("Mul", ["style_mean", "zero"], ["style_0"]),
        helper.make_node("Mul", ["speed", "zero"], ["speed_0"]),
        helper.make_node("Add", ["wave", "style_0"], ["w1"]),
        helper.make_node("Add", ["w1", "speed_0"], ["w2"]),
        helper.make_node("Mul", ["w2", "half"], ["audio"]),
    ]
    graph = helper.make_graph(
        nodes, "tiny_kokoro",
        [helper.make_tensor_value_info("tokens", TensorProto.INT64, [1, "n"]),
         helper.make_tensor_value_info("style", TensorProto.FLOAT, [1, 256]),
         helper.make_tensor_value_info("speed", TensorProto.FLOAT, [1])],
        [helper.make_tensor_value_info("audio", TensorProto.FLOAT, ["samples"])],
        [numpy_helper.from_array(v, k) for k, v in const.items()])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    meta = {"model_type": "kokoro", "sample_rate": "24000", "version": "1", "n_speakers": str(SPEAKERS),
            "has_espeak": "1", "voice": "en-us", "style_dim": "510,1,256", "speaker_names": "af,am"}
    for key, value in meta.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.checker.check_model(model)
    os.makedirs(folder, exist_ok=True)
    onnx.save(model, os.path.join(folder, "model.onnx"))
    np.zeros((SPEAKERS, 510, 256), np.float32).tofile(os.path.join(folder, "voices.bin"))
    with open(os.path.join(folder, "tokens.txt"), "w", encoding="utf-8") as f:
        f.writelines(f"{s} {i}\n" for i, s in enumerate(SYMBOLS))
    return folder
