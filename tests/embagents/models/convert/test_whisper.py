"""Whisper's CTranslate2 weights rewritten as sherpa-onnx's encoder/decoder: the interface sherpa-onnx reads.

That the result transcribes real speech is tested in tests/embagents/models/backends/test_sherpa_stt.py.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

pytest.importorskip("onnx")

from embagents.models.convert.whisper import gpt2_token_bytes, read_ct2_model  # noqa: E402


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
