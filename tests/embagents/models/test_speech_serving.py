"""The speech model actor (the ``transcribe`` task) serves real speech and refuses bad requests at once."""

from __future__ import annotations

import re
from collections.abc import Iterator

import numpy as np
import pytest

pytest.importorskip("sherpa_onnx")

from actors import ActorSystem  # noqa: E402
from embagents.models import BadRequest, LocalModelClient  # noqa: E402
from embagents.models.actor import ModelActor  # noqa: E402


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


def test_the_model_refuses_audio_at_another_rate_and_keeps_serving(whisper: str, speech_clip: tuple) -> None:
    client = LocalModelClient(whisper)
    with pytest.raises(BadRequest, match="audio must be 16000 Hz, got sample_rate=8000; resample it first"):
        client.transcribe(np.zeros(800, np.float32), sample_rate=8000)
    with pytest.raises(BadRequest, match="dtype int32"):
        client.transcribe(np.zeros(800, np.int32))
    assert words(client.transcribe(speech_clip[0][:44000])["text"]) == "ever tried ever failed"


def test_a_long_utterance_crosses_through_shared_memory_and_is_transcribed(whisper: str, speech_clip: tuple) -> None:
    client = LocalModelClient(whisper)
    clip = speech_clip[0].astype(np.float32) / 32768  # 10 s: 640 KB, far above the inline limit
    out = client.transcribe(clip)
    assert words(out["text"]) == "ever tried ever failed no matter try again fail again fail better"
    assert out["seconds"] == len(clip) / 16000
    assert client.transcribe(np.zeros(0, np.float32))["text"] == ""  # empty: answered, not refused
    with pytest.raises(BadRequest, match="serves task 'transcribe', not 'detect'"):
        client.infer("detect", {"audio": clip[:10]})


def test_a_model_directory_the_user_gives_is_served_the_same_way(system: ActorSystem, tiny_paraformer: str) -> None:
    from embagents.models import SpeechToTextModel

    model = SpeechToTextModel(name="para", local_model_path=tiny_paraformer)
    system.spawn(ModelActor, model.name, model.kind, model.resolve(), model.options(), True, wait=60)
    assert LocalModelClient(model).transcribe(np.zeros(16000, np.float32))["text"] == "hello robot"
    stats = system.ref("para").ask("stats", timeout=10).get()
    assert (stats["served"], stats["kind"], stats["model"]) == (1, "stt", tiny_paraformer)


def test_a_submitted_request_is_answered_later_or_cancelled_without_keeping_its_shared_memory(
        whisper: str, speech_clip: tuple) -> None:
    from actors.runtime import current

    client = LocalModelClient(whisper)
    clip = speech_clip[0].astype(np.float32) / 32768  # 640 KB: through shared memory
    pending = client.submit("transcribe", {"audio": clip[:44000]})  # sent: the caller goes on meanwhile
    assert words(pending.result()["text"]) == "ever tried ever failed"
    with pytest.raises(RuntimeError, match="taken once"):
        pending.result()
    client.submit("transcribe", {"audio": clip}).cancel()  # the user went on: not wanted
    # The next request on the same connection gets its own answer, not the cancelled one's ...
    assert words(client.transcribe(clip[:44000])["text"]) == "ever tried ever failed"
    # ... and the cancelled one's segment is free again: a request of its size reuses it.
    pool = current().pool
    before = pool.segment_count
    assert words(client.transcribe(clip)["text"]).startswith("ever tried ever failed")
    assert pool.segment_count == before, "the cancelled request's shared memory was kept"
