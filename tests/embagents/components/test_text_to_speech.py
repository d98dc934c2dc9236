"""The TextToSpeech component against a real Piper voice actor, checked by ear: a real Whisper actor."""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest

pytest.importorskip("sherpa_onnx")
pytest.importorskip("espeakng_loader")

from actors import ActorSystem  # noqa: E402
from embagents.components import HealthStatus, TextToSpeech, TextToSpeechConfig  # noqa: E402
from embagents.components.audio_format import to_mono_16k  # noqa: E402
from embagents.models import LocalModelClient, TextToSpeechModel  # noqa: E402
from embagents.models.actor import ModelActor  # noqa: E402
from embagents.models.protocol import BadRequest  # noqa: E402
from embagents.msgs import Audio, StreamingString, String, VoiceStage
from embagents.topic import Topic  # noqa: E402


def words(text: str) -> str:
    return " ".join(re.findall(r"[a-z']+", text.lower()))


@pytest.fixture(scope="module")
def system(piper_dir: str, whisper_dir: str) -> Iterator[ActorSystem]:
    with ActorSystem() as asys:
        asys.spawn(ModelActor, "joe", "tts", piper_dir, {"threads": 1}, True, wait=60)
        asys.spawn(ModelActor, "whisper", "stt", whisper_dir, {"threads": 1}, True, wait=60)
        yield asys


class Loop:
    """The component's thread, played by the test: call_later queues, run() drains."""

    def __init__(self) -> None:
        self.due: list[Callable[[], None]] = []

    def call_later(self, delay: float, fn: Callable[[], None]) -> None:
        self.due.append(fn)

    def turn(self) -> bool:
        if not self.due:
            return False
        self.due.pop(0)()
        return True

    def run(self) -> None:
        while self.turn():
            pass


def voice(system: ActorSystem, model: str = "joe", **config: Any) -> tuple[TextToSpeech, list[Audio], Loop]:
    comp = TextToSpeech(name="voice", inputs=[Topic("answer", String), Topic("tokens", StreamingString)],
                        outputs=[Topic("speaker", Audio, keep="all")], model_client=LocalModelClient(model),
                        config=TextToSpeechConfig(**config))
    sent: list[Audio] = []
    loop = Loop()
    comp.attach(lambda topic, msg: sent.append(msg), None, loop.call_later)
    comp.on_configure()
    return comp, sent, loop


def utterances(sent: list[Audio]) -> list[np.ndarray]:
    """The audio between end-of-utterance markers, as 16 kHz mono float32."""
    out: list[np.ndarray] = []
    current: list[np.ndarray] = []
    for a in sent:
        if a.data.size == 0:
            out.append(np.concatenate(current) if current else np.zeros(0, np.float32))
            current = []
        else:
            current.append(to_mono_16k(a)[0])
    return out


def overlap(said: str, heard: str) -> float:
    """The share of the said words the recognizer heard (tiny.en mishears a word now and then)."""
    want, got = words(said).split(), set(words(heard).split())
    return sum(w in got for w in want) / len(want)


def hear(samples: np.ndarray) -> str:
    return words(LocalModelClient("whisper").transcribe(samples)["text"])


def test_a_spoken_sentence_is_heard_back_by_a_real_recognizer(system: ActorSystem) -> None:
    comp, sent, loop = voice(system)
    assert comp.on_message("answer", String(data="The red cup is on the kitchen table."))
    assert comp.execute()
    loop.run()
    assert all(a.sample_rate == 22050 and a.data.dtype == np.float32 for a in sent if a.data.size)
    [speech] = utterances(sent)
    assert 1.0 < len(speech) / 16000 < 6.0
    heard = hear(speech)
    assert overlap("The red cup is on the kitchen table.", heard) >= 0.6, heard  # 25 tries: never below 0.75
    assert comp.spoken == 1 and comp.health.status == HealthStatus.HEALTHY


def test_a_stream_is_spoken_sentence_by_sentence_while_it_is_still_written(system: ActorSystem) -> None:
    comp, sent, loop = voice(system)
    for delta in ["Hello", " there", ". I am", " a robot", ". I can"]:
        comp.on_message("tokens", StreamingString(data=delta, stream_id="s1"))
        comp.execute()
        loop.run()
    first = [a for a in sent if a.data.size]
    assert len(first) == 2, "each whole sentence is spoken as soon as it is complete"
    assert all(a.data.size for a in sent), "no end of utterance before the stream is done"
    comp.on_message("tokens", StreamingString(data=" see you.", stream_id="s1"))
    comp.execute()
    comp.on_message("tokens", StreamingString(data="", done=True, stream_id="s1"))
    comp.execute()
    loop.run()
    [speech] = utterances(sent)
    heard = hear(speech)
    assert overlap("Hello there. I am a robot. I can see you.", heard) >= 0.75, heard


def test_say_interrupts_what_is_queued_and_speaks_at_once(system: ActorSystem) -> None:
    comp, sent, loop = voice(system)
    comp.on_message("answer", String(data="The red cup is on the table. The door is open. The lamp is green."))
    comp.execute()  # speaks the first sentence and schedules the rest, one per turn
    assert comp.spoken == 1 and len(loop.due) == 1
    assert comp.say("Stop right there.") == 1
    loop.run()
    first, second = utterances(sent)
    heard_first = hear(first)
    # Piper's VITS samples its noise afresh each time: judge by share of words, not an exact transcript.
    assert overlap("The red cup is on the table.", heard_first) >= 0.5, heard_first
    assert not {"door", "open", "lamp", "green"} & set(heard_first.split()), heard_first
    assert "stop" in hear(second)
    assert comp.spoken == 2, "the door and the lamp were dropped"
    assert comp.stop_playback() == 0


def test_text_with_nothing_to_say_is_skipped_and_the_next_is_spoken(system: ActorSystem) -> None:
    comp, sent, loop = voice(system)
    comp.on_message("answer", String(data=" ... ?! "))
    comp.execute()
    loop.run()
    assert sent == [] and comp.spoken == 0
    comp.on_message("answer", String(data="Done."))
    comp.execute()
    loop.run()
    assert comp.spoken == 1 and len(utterances(sent)) == 1
    with pytest.raises(BadRequest, match="no speakable characters"):
        list(LocalModelClient("joe").speak("?!"))


def test_a_request_cancelled_halfway_leaves_the_voice_free(system: ActorSystem) -> None:
    client = LocalModelClient("joe")
    stream = client.speak("This is the first sentence. This is the second one. And a third.")
    first = next(stream)
    assert first["audio"].size and first["sample_rate"] == 22050
    stream.close()  # cancels the rest in the model actor
    chunks = list(client.speak("Still here."))
    assert chunks[-1]["done"] and chunks[0]["audio"].size
    assert "still here" in hear(to_mono_16k(Audio(data=chunks[0]["audio"], sample_rate=22050))[0])


def test_a_voice_folder_missing_a_file_names_it_and_how_to_prepare_the_default(tmp_path: Any) -> None:
    (tmp_path / "model.onnx").write_bytes(b"")
    problem = TextToSpeechModel(name="v", local_model_path=str(tmp_path)).file_problem()
    assert problem is not None and "tokens.txt, voice.json" in problem and "piper_joe_dir" in problem
    problem = TextToSpeechModel(name="v", local_model_path=str(tmp_path / "nope")).file_problem()
    assert problem is not None and "not found" in problem
    assert TextToSpeechModel(name="v").file_problem() is None


def test_a_kokoro_voice_speaks_from_its_own_model_actor(system: ActorSystem, tiny_kokoro: str) -> None:
    system.spawn(ModelActor, "kokoro", "tts", tiny_kokoro, {"speaker_id": 1}, True, wait=60)
    try:
        comp, sent, loop = voice(system, model="kokoro")
        assert comp.on_message("answer", String(data="Hello there. I am a robot."))
        assert comp.execute()
        loop.run()
        chunks = [a for a in sent if a.data.size]
        assert len(chunks) == 2 and {a.sample_rate for a in chunks} == {24000}  # a chunk per sentence
        assert sent[-1].data.size == 0 and comp.spoken == 2
    finally:
        system.stop("kokoro")


def test_each_answer_publishes_its_first_audio_once_on_a_voice_stage_output_and_audio_only_on_audio(
        system: ActorSystem) -> None:
    comp = TextToSpeech(name="voice", inputs=[Topic("answer", String)],
                        outputs=[Topic("speaker", Audio, keep="all"), Topic("stages", VoiceStage, keep="all")],
                        model_client=LocalModelClient("joe"))
    sent: list[tuple[str, Any]] = []
    loop = Loop()
    comp.attach(lambda topic, msg: sent.append((topic, msg)), None, loop.call_later)
    comp.on_configure()
    for text in ("The door is open. The lamp is green.", "Hello there."):
        assert comp.on_message("answer", String(data=text)) and comp.execute()
        loop.run()
    topics = [t for t, _ in sent]
    assert all(isinstance(m, Audio) for t, m in sent if t == "speaker")
    stages = [m for t, m in sent if t == "stages"]
    assert [(m.stage, m.source) for m in stages] == [("tts_first_audio", "voice")] * 2, "one per answer, not per sentence"
    first_audio = [i for i, (t, m) in enumerate(sent) if t == "speaker" and m.data.size]
    ends = [i for i, (t, m) in enumerate(sent) if t == "speaker" and not m.data.size]
    assert topics.index("stages") < first_audio[0] and ends[0] < len(topics) - 1 - topics[::-1].index("stages")
