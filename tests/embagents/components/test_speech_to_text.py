"""The SpeechToText component against a real Whisper model actor, on a real speech clip."""

from __future__ import annotations

import logging
import re
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

pytest.importorskip("sherpa_onnx")

from actors import ActorSystem  # noqa: E402
from embagents.components import ComponentError, HealthStatus, SpeechToText, SpeechToTextConfig  # noqa: E402
from embagents.models import LocalModelClient, SpeechToTextModel  # noqa: E402
from embagents.models.actor import ModelActor  # noqa: E402
from embagents.models.files.speech import SPEECH_CLIP_WORDS  # noqa: E402
from embagents.msgs import Audio, StreamingString, String  # noqa: E402
from embagents.topic import Topic  # noqa: E402

mic = Topic("mic", Audio, keep="all")


def words(text: str) -> str:
    return " ".join(re.findall(r"[a-z']+", text.lower()))


@pytest.fixture(scope="module")
def system(whisper_dir: str) -> Iterator[ActorSystem]:
    with ActorSystem() as asys:
        asys.spawn(ModelActor, "whisper", "stt", whisper_dir, {"threads": 1}, True, wait=60)
        yield asys


@pytest.fixture
def whisper(system: ActorSystem) -> str:
    return "whisper"


def ears(model: str, partials: bool = False, **config: Any) -> tuple[SpeechToText, list[Any]]:
    outputs = [Topic("heard", String)] + ([Topic("hearing", StreamingString)] if partials else [])
    comp = SpeechToText(name="ears", inputs=[mic], outputs=outputs, model_client=LocalModelClient(model),
                        config=SpeechToTextConfig(**config))
    sent: list[Any] = []
    comp.attach(lambda topic, msg: sent.append(msg))
    comp.on_configure()
    return comp, sent


def play(comp: SpeechToText, samples: np.ndarray, rate: int = 16000, channels: int = 1, chunk_s: float = 0.1) -> None:
    """Feed the clip as a microphone would (chunks of 100 ms), then the end-of-stream marker."""
    step = int(rate * chunk_s) * channels
    for i in range(0, len(samples), step):
        assert comp.on_message("mic", Audio(data=samples[i:i + step], sample_rate=rate, channels=channels))
        assert comp.execute()
    assert comp.on_message("mic", Audio(data=np.zeros(0, samples.dtype), sample_rate=rate, channels=channels))
    assert comp.execute()


def test_the_clip_in_mic_sized_chunks_is_heard_phrase_by_phrase(whisper: str, speech_clip: tuple) -> None:
    comp, sent = ears(whisper, min_silence_ms=300)
    play(comp, speech_clip[0])
    assert all(isinstance(m, String) for m in sent) and len(sent) == 6
    assert " ".join(words(m.data) for m in sent) == SPEECH_CLIP_WORDS
    assert comp.health.status == HealthStatus.HEALTHY


def test_stereo_at_44_1_khz_is_resampled_with_a_log_line(whisper: str, speech_clip: tuple,
                                                        caplog: pytest.LogCaptureFixture) -> None:
    from scipy.signal import resample_poly

    mono = resample_poly(speech_clip[0].astype(np.float32) / 32768, 441, 160).astype(np.float32)
    stereo = np.column_stack([mono, mono]).reshape(-1)  # interleaved
    comp, sent = ears(whisper, min_silence_ms=300)
    with caplog.at_level(logging.INFO, logger="embagents.component.ears"):
        play(comp, stereo, rate=44100, channels=2)
    notes = [r.getMessage() for r in caplog.records if "resampled" in r.getMessage()]
    assert notes == ["component 'ears' (SpeechToText): audio at 44100 Hz, 2 channels: mixed down and resampled to 16 kHz mono"]  # once
    assert " ".join(words(m.data) for m in sent) == SPEECH_CLIP_WORDS


def test_partial_transcripts_stream_while_the_utterance_goes_on(whisper: str, speech_clip: tuple) -> None:
    comp, sent = ears(whisper, partials=True, min_silence_ms=3000, partial_interval_ms=2000)  # one long utterance
    play(comp, speech_clip[0])
    partial = [m for m in sent if isinstance(m, StreamingString)]
    final = [m for m in sent if isinstance(m, String)]
    assert len(final) == 1 and words(final[0].data) == SPEECH_CLIP_WORDS
    assert len(partial) >= 3 and [m.done for m in partial] == [False] * (len(partial) - 1) + [True]
    assert {m.stream_id for m in partial} == {"ears-1"} and partial[-1].data == final[0].data
    assert words(partial[0].data) != SPEECH_CLIP_WORDS and SPEECH_CLIP_WORDS.startswith(words(partial[0].data)[:9])


def test_the_wake_phrase_gates_what_is_passed_on(whisper: str, speech_clip: tuple) -> None:
    comp, sent = ears(whisper, min_silence_ms=300, wake_phrase="try again")
    play(comp, speech_clip[0])
    # "Try again." alone opens the gate; the next phrase passes; the gate closes again.
    assert [words(m.data) for m in sent] == ["fail again"]
    comp, sent = ears(whisper, min_silence_ms=300, wake_phrase="hey robot")
    play(comp, speech_clip[0])
    assert sent == []
    comp, sent = ears(whisper, min_silence_ms=300, wake_phrase="ever")  # the phrase, then what is asked
    play(comp, speech_clip[0])
    assert [m.data for m in sent] == ["tried.", "failed."]


def test_bad_audio_is_a_clear_skip_and_the_next_chunk_is_heard(whisper: str, speech_clip: tuple) -> None:
    comp, sent = ears(whisper, enable_vad=False)
    comp.on_message("mic", Audio(data=np.zeros(1600, np.float64)))
    comp.execute()
    assert comp.health.status == HealthStatus.ALGORITHM_FAILURE
    assert "dtype float64; send int16 PCM or float32" in comp.health.text
    comp.on_message("mic", Audio(data=np.zeros(1600, np.int16), sample_rate=0))
    comp.execute()
    assert "sample_rate must be a positive integer (Hz), got 0" in comp.health.text
    comp.on_message("mic", Audio(data=np.zeros(1601, np.int16), channels=2))
    comp.execute()
    assert "not a multiple of its 2 channels" in comp.health.text
    assert sent == []
    comp.on_message("mic", Audio(data=speech_clip[0][:44000]))  # "Ever tried, ever failed."
    assert comp.execute() and comp.health.status == HealthStatus.HEALTHY
    assert [words(m.data) for m in sent] == ["ever tried ever failed"]


def test_an_empty_utterance_and_silence_publish_nothing(whisper: str, caplog: pytest.LogCaptureFixture) -> None:
    comp, sent = ears(whisper, enable_vad=False)
    with caplog.at_level(logging.INFO, logger="embagents.component.ears"):
        comp.on_message("mic", Audio(data=np.zeros(0, np.int16)))
        assert comp.execute()
        comp.on_message("mic", Audio(data=np.zeros(16000, np.int16)))
        assert comp.execute()
    assert sent == [] and any("heard nothing in 1.0 s" in r.getMessage() for r in caplog.records)
    comp, sent = ears(whisper)  # with VAD: silence never reaches the model
    comp.on_message("mic", Audio(data=np.zeros(32000, np.int16)))
    assert comp.execute() and comp.flush() == 0 and sent == []


def test_a_model_directory_missing_a_file_is_named_before_anything_starts(tmp_path: Any) -> None:
    (tmp_path / "encoder.onnx").write_bytes(b"")
    (tmp_path / "tokens.txt").write_bytes(b"")
    model = SpeechToTextModel(name="ears_model", local_model_path=str(tmp_path))
    problem = model.file_problem()
    assert problem is not None and "misses its decoder file" in problem and "whisper_tiny_en_dir" in problem
    with pytest.raises(FileNotFoundError, match="misses its decoder file"):
        model.resolve()


def test_embagents_check_names_the_missing_file_and_starts_nothing(tmp_path: Any) -> None:
    import subprocess
    import sys

    (tmp_path / "model").mkdir()
    for name in ("encoder.onnx", "tokens.txt"):
        (tmp_path / "model" / name).write_bytes(b"")
    system = tmp_path / "system.py"
    system.write_text(
        "from embagents.components import SpeechToText\n"
        "from embagents.models import LocalModelClient, SpeechToTextModel\n"
        "from embagents.msgs import Audio, String\n"
        "from embagents.system import System\n"
        "from embagents.topic import Topic\n"
        f"m = SpeechToTextModel(name='whisper', local_model_path={str(tmp_path / 'model')!r})\n"
        "system = System([SpeechToText(name='ears', inputs=[Topic('mic', Audio)], outputs=[Topic('heard', String)],\n"
        "                              model_client=LocalModelClient(m))], models=[m], name='broken')\n")
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "check", str(system)], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 1
    assert "model 'whisper': the whisper model in" in out.stdout + out.stderr
    assert "misses its decoder file (*decoder*.onnx); it has encoder.onnx, tokens.txt" in out.stdout + out.stderr


def test_a_client_that_cannot_transcribe_is_a_declaration_error() -> None:
    class Chatty:
        name = "chatty"

        def chat(self, messages: list, **options: Any) -> str:
            return "hi"

    with pytest.raises(ComponentError, match="model client .* cannot transcribe"):
        SpeechToText(name="ears", inputs=[mic], outputs=[Topic("heard", String)], model_client=Chatty())


def test_a_wake_word_model_that_cannot_be_had_is_named_with_the_alternative(whisper: str, tmp_path: Any) -> None:
    # openWakeWord ships no model on PyPI: what can be tested here is how a missing one is reported.
    with pytest.raises(FileNotFoundError, match="openWakeWord model not found: .*use wake_phrase='hey robot'"):
        ears(whisper, wake_word_model=str(tmp_path / "hey_robot.onnx"))
    try:
        import openwakeword  # noqa: F401
    except ImportError:
        (tmp_path / "hey_robot.onnx").write_bytes(b"")
        with pytest.raises(ModuleNotFoundError, match="pip install openwakeword"):
            ears(whisper, wake_word_model=str(tmp_path / "hey_robot.onnx"))


def test_a_model_actor_that_dies_mid_utterance_is_reported_and_its_successor_is_heard(
        system: ActorSystem, whisper_dir: str, speech_clip: tuple) -> None:
    import signal
    import threading

    from embagents.models import client as client_module
    from tests.helpers import wait_until

    system.spawn(ModelActor, "doomed", "stt", whisper_dir, {"threads": 1}, True, wait=60)
    comp, sent = ears("doomed", enable_vad=False)
    first = int(repr(client_module._req_ids)[len("count("):-1])
    comp.on_message("mic", Audio(data=np.tile(speech_clip[0], 4)))  # 40 s: seconds of work for the model
    step = threading.Thread(target=comp.execute)
    step.start()
    wait_until(lambda: int(repr(client_module._req_ids)[len("count("):-1]) > first, 10, "the request sent")
    system.signal("doomed", signal.SIGKILL)
    step.join(timeout=25)
    assert not step.is_alive() and sent == []  # the step ended: nothing stuck
    assert comp.health.status == HealthStatus.ALGORITHM_FAILURE and "went away" in comp.health.text
    system.stop("doomed")
    system.spawn(ModelActor, "doomed", "stt", whisper_dir, {"threads": 1}, True, wait=60)  # as a supervisor would
    comp.on_message("mic", Audio(data=speech_clip[0][:44000]))
    assert comp.execute() and [words(m.data) for m in sent] == ["ever tried ever failed"]
    assert comp.health.status == HealthStatus.HEALTHY
