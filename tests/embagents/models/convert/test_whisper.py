"""Whisper's CTranslate2 weights rewritten as sherpa-onnx's encoder/decoder: the interface sherpa-onnx reads.

That the result transcribes real speech is tested in tests/embagents/models/backends/test_sherpa_stt.py.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

pytest.importorskip("onnx")

from embagents.models.convert.whisper import (  # noqa: E402
    OUT_BLOCK,
    _uint8_blocks,
    gpt2_token_bytes,
    read_ct2_model,
)


def test_the_prepared_encoder_has_the_interface_and_metadata_sherpa_onnx_reads(whisper_dir: str) -> None:
    import onnx

    enc = onnx.load(os.path.join(whisper_dir, "encoder.onnx"), load_external_data=False)
    meta = {p.key: p.value for p in enc.metadata_props}
    assert [i.name for i in enc.graph.input] == ["mel"]
    assert [o.name for o in enc.graph.output] == ["n_layer_cross_k", "n_layer_cross_v"]
    assert (meta["n_text_layer"], meta["n_text_ctx"], meta["sot_sequence"], meta["eot"]) == ("4", "448", "50257", "50256")
    assert meta["is_multilingual"] == "0" and meta["no_timestamps"] == "50362"
    dec = onnx.load(os.path.join(whisper_dir, "decoder.onnx"), load_external_data=False)
    assert [i.name for i in dec.graph.input] == ["tokens", "in_n_layer_self_k_cache", "in_n_layer_self_v_cache",
                                                 "n_layer_cross_k", "n_layer_cross_v", "offset"]
    assert [o.name for o in dec.graph.output] == ["logits", "out_n_layer_self_k_cache", "out_n_layer_self_v_cache"]


def test_the_output_layer_is_stored_in_8_bits_within_half_a_step_of_the_embeddings(whisper_dir: str) -> None:
    # fp32, the 51864 x 384 output layer (80 MB) is read whole for every token and evicts the other core's cache.
    import numpy as np
    import onnx
    from onnx import numpy_helper

    from embagents.models.files.speech import _ct2_whisper_dir

    dec = onnx.load(os.path.join(whisper_dir, "decoder.onnx"))
    (out,) = [n for n in dec.graph.node if "logits" in n.output]
    attrs = {a.name: onnx.helper.get_attribute_value(a) for a in out.attribute}
    assert (out.op_type, out.domain, attrs["bits"], attrs["block_size"]) == ("MatMulNBits", "com.microsoft", 8, OUT_BLOCK)
    init = {i.name: numpy_helper.to_array(i) for i in dec.graph.initializer}
    q, scale, zero = (init[name] for name in out.input[1:4])
    emb = read_ct2_model(os.path.join(_ct2_whisper_dir(progress=False), "model.bin"))["decoder/embeddings/weight"]
    step = np.repeat(scale.reshape(q.shape[:2]), OUT_BLOCK, axis=1)
    back = (q.astype(np.float32) - zero.reshape(q.shape[:2])[..., None]).reshape(emb.shape) * step
    assert np.all(np.abs(back - emb) <= step * 0.5 + 1e-6)
    with pytest.raises(ValueError, match="not a multiple of the 32-value quantization block"):
        _uint8_blocks(np.ones((4, 40), np.float32), 32)


def test_tokens_are_base64_of_the_bpe_bytes(whisper_dir: str) -> None:
    import base64

    lines = Path(whisper_dir, "tokens.txt").read_text().splitlines()
    assert len(lines) == 50256
    assert base64.b64decode(lines[262].split()[0]) == b" the" == gpt2_token_bytes("Ġthe")


def test_a_file_that_is_not_a_ctranslate2_model_is_refused(tmp_path: Path) -> None:
    bad = tmp_path / "model.bin"
    bad.write_bytes(b"\x05\x00\x00\x00garbage")
    with pytest.raises(ValueError, match="binary version 5"):
        read_ct2_model(str(bad))
