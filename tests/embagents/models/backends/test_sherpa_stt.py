"""Whisper tiny.en rewritten for sherpa-onnx transcribes real speech; model directories are checked."""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("sherpa_onnx")

from embagents.components.vad import SpeechSegmenter  # noqa: E402
from embagents.models.backends.sherpa_stt import (  # noqa: E402
    SherpaRecognizer,
    SpeechModelError,
    detect_stt_model,
)
from embagents.models.files.speech import SPEECH_CLIP_WORDS, silero_vad_path  # noqa: E402


def words(text: str) -> str:
    return " ".join(re.findall(r"[a-z']+", text.lower()))


@pytest.fixture(scope="module")
def recognizer(whisper_dir: str) -> SherpaRecognizer:
    return SherpaRecognizer(whisper_dir, threads=1)


def test_the_prepared_whisper_transcribes_the_real_clip_word_for_word(recognizer: SherpaRecognizer,
                                                                      speech_clip: tuple[np.ndarray, int]) -> None:
    samples, rate = speech_clip
    assert rate == 16000 and recognizer.family == "whisper"
    assert words(recognizer.transcribe(samples)) == SPEECH_CLIP_WORDS


def test_audio_longer_than_whisper_hears_at_once_is_transcribed_in_pieces(recognizer: SherpaRecognizer,
                                                                         speech_clip: tuple[np.ndarray, int]) -> None:
    samples = np.tile(speech_clip[0], 4)  # 40 s: more than Whisper's 30 s window
    said = words(recognizer.transcribe(samples))
    assert said.count("fail better") >= 3 and said.startswith("ever tried ever failed") and said.endswith("fail better")


def test_silence_and_empty_audio_give_no_words(recognizer: SherpaRecognizer) -> None:
    assert recognizer.transcribe(np.zeros(0, np.float32)) == ""
    assert recognizer.transcribe(np.zeros(16000, np.float32)) == ""  # not Whisper's "[ Silence ]"


def test_wrong_dtype_and_shape_say_what_to_send(recognizer: SherpaRecognizer) -> None:
    with pytest.raises(ValueError, match="float32 in \\[-1, 1\\] or int16 samples, got dtype float64"):
        recognizer.transcribe(np.zeros(100))
    with pytest.raises(ValueError, match="1-D mono samples, got shape \\(2, 100\\)"):
        recognizer.transcribe(np.zeros((2, 100), np.float32))


def test_a_directory_missing_a_file_names_it_and_the_default(whisper_dir: str, tmp_path: Path) -> None:
    broken = tmp_path / "whisper"
    broken.mkdir()
    shutil.copy(os.path.join(whisper_dir, "tokens.txt"), broken)
    os.symlink(os.path.join(whisper_dir, "encoder.onnx"), broken / "encoder.onnx")
    with pytest.raises(SpeechModelError, match=r"whisper model .* misses its decoder file \(\*decoder\*.onnx\).*"
                                               r"whisper_tiny_en_dir"):
        detect_stt_model(str(broken))
    (broken / "tokens.txt").unlink()
    os.symlink(os.path.join(whisper_dir, "decoder.onnx"), broken / "decoder.onnx")
    with pytest.raises(SpeechModelError, match=r"misses its tokens file \(tokens.txt\)"):
        detect_stt_model(str(broken))
    with pytest.raises(SpeechModelError, match="not found"):
        detect_stt_model(str(tmp_path / "nowhere"))


def test_families_are_found_from_the_files(tmp_path: Path) -> None:
    layouts = {
        "transducer": ["encoder-epoch-99.onnx", "decoder-epoch-99.onnx", "joiner-epoch-99.onnx"],
        "moonshine": ["preprocess.onnx", "encode.int8.onnx", "uncached_decode.int8.onnx", "cached_decode.int8.onnx"],
        "paraformer": ["model.onnx", "model.int8.onnx"],
        "whisper": ["tiny.en-encoder.onnx", "tiny.en-encoder.int8.onnx", "tiny.en-decoder.onnx"],
    }
    for family, names in layouts.items():
        folder = tmp_path / family
        folder.mkdir()
        for n in [*names, "tokens.txt"]:
            (folder / n).write_bytes(b"")
        found, files = detect_stt_model(str(folder))
        assert found == family
        assert all(".int8." not in f for role, f in files.items() if family != "moonshine")  # full precision first
    assert os.path.basename(detect_stt_model(str(tmp_path / "moonshine"))[1]["cached_decoder"]) == "cached_decode.int8.onnx"


def test_vad_cuts_the_clip_into_its_six_phrases(recognizer: SherpaRecognizer, speech_clip: tuple[np.ndarray, int]) -> None:
    samples = speech_clip[0].astype(np.float32) / 32768
    vad = SpeechSegmenter(silero_vad_path(progress=False), min_silence_ms=300)
    utterances: list[np.ndarray] = []
    starts: list[int] = []
    for i in range(0, len(samples), 1600):  # 100 ms chunks, as a microphone gives them
        utterances += vad.feed(samples[i:i + 1600])
        starts += vad.last_starts
    utterances += vad.flush()
    starts += vad.last_starts
    assert len(utterances) == 6 and all(0.5 < len(u) / 16000 < 2.0 for u in utterances)
    assert 0.2 < starts[0] / 16000 < 0.5 and 7.5 < starts[-1] / 16000 < 8.5 and starts == sorted(starts)
    assert all(np.array_equal(u, samples[s:s + len(u)]) for u, s in zip(utterances, starts, strict=True))
    said = " ".join(words(recognizer.transcribe(u)) for u in utterances)
    assert said == SPEECH_CLIP_WORDS
    assert vad.feed(np.zeros(16000, np.float32)) == [] and vad.flush() == []  # silence is no utterance


def test_vad_settings_are_checked() -> None:
    with pytest.raises(ValueError, match="threshold must be in \\(0, 1\\)"):
        SpeechSegmenter(silero_vad_path(progress=False), threshold=1.5)
    with pytest.raises(FileNotFoundError, match="silero_vad_path"):
        SpeechSegmenter("/nonexistent/silero.onnx")


@pytest.mark.parametrize(("fixture", "family"), [("tiny_paraformer", "paraformer"), ("tiny_transducer", "transducer"),
                                                ("tiny_moonshine", "moonshine")])
def test_a_user_model_directory_of_another_family_loads_and_decodes(fixture: str, family: str,
                                                                    request: pytest.FixtureRequest) -> None:
    stt = SherpaRecognizer(request.getfixturevalue(fixture))
    assert stt.family == family
    assert stt.transcribe(np.zeros(16000, np.float32)) == "hello robot"
