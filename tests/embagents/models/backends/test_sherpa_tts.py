"""sherpa-onnx's offline TTS on a Kokoro voice folder (a tiny one of Kokoro's shape: no release can be had here)."""

from __future__ import annotations

import os
from typing import Any

import numpy as np
import pytest

pytest.importorskip("sherpa_onnx")
pytest.importorskip("espeakng_loader")

from embagents.models import TextToSpeechModel  # noqa: E402
from embagents.models.backends.sherpa_tts import SherpaSpeaker, voice_family  # noqa: E402
from tests.embagents.fixtures.tiny_kokoro import SAMPLES_PER_TOKEN  # noqa: E402


def test_a_kokoro_folder_speaks_each_sentence_at_its_own_rate(tiny_kokoro: str) -> None:
    voice = SherpaSpeaker(tiny_kokoro, speaker_id=1)
    assert voice_family(tiny_kokoro) == "kokoro"
    assert voice.describe() | {"path": ""} == {"sample_rate": 24000, "voice": "en-us", "path": "",
                                               "family": "kokoro", "speakers": 2}
    said = list(voice.speak("Hello there. I am a robot."))
    assert [sr for _, sr, _ in said] == [24000, 24000]
    for samples, _, phonemes in said:
        # Every phoneme reached the model as a token (sherpa-onnx pads one at each end).
        assert samples.dtype == np.float32 and len(samples) == (len(phonemes) + 2) * SAMPLES_PER_TOKEN
    assert "ɹˈoʊb" in said[1][2]


def test_a_speaker_the_voice_does_not_have_is_refused_by_number(tiny_kokoro: str) -> None:
    with pytest.raises(ValueError, match=r"speaker_id 2 is not one of this voice's 2 speakers \(0\.\.1\)"):
        SherpaSpeaker(tiny_kokoro, speaker_id=2)


def test_a_kokoro_folder_missing_a_file_names_it(tiny_kokoro: str, tmp_path: Any) -> None:
    for name in ("model.onnx", "voices.bin"):
        os.symlink(os.path.join(tiny_kokoro, name), tmp_path / name)
    problem = TextToSpeechModel(name="kokoro", local_model_path=str(tmp_path)).file_problem()
    assert problem is not None and "Kokoro voice folder" in problem and "lacks tokens.txt" in problem


def test_a_kokoro_repo_on_an_unreachable_hub_says_so_and_what_to_give_instead(monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("huggingface_hub")
    from embagents.models.files.hub import HubUnreachableError

    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_HUB_CACHE", "/nonexistent-embagents-cache")
    voice = TextToSpeechModel(name="kokoro", local_model_path="csukuangfj/kokoro-en-v0_19")
    assert voice.file_problem() is None  # a repo is fetched at start, not checked as a path
    with pytest.raises(HubUnreachableError, match=r"fetch 'csukuangfj/kokoro-en-v0_19' \(HF_HUB_OFFLINE is set\).*"
                                                  r"Give the path of a Kokoro folder"):
        voice.resolve()
