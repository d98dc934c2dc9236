"""Microphone and Speaker on real PortAudio and ALSA, each in its own actor process, with no sound card.

ALSA's ``file`` plugin makes the devices (defined in a private config that
``ALSA_CONFIG_PATH`` hands the actor processes): ``robotmic`` captures from a
raw 16 kHz S16_LE file, ``robotspeaker`` writes what it plays to one. Their
slave is ALSA's ``null`` PCM, which does not pace: a device is as fast as it
is read, so the Microphone (which reads what its buffer holds at each step)
hears the clip about ``buffer_ms / chunk_ms`` times faster than real time: 6
chunks of 100 ms a step, with alsa-lib 1.2.8 and PortAudio 19.6. How far it has
read when the last phrase is heard is a race between its next step and Whisper
(96 chunks, 16 steps, where Whisper answers within the 100 ms to the next step,
as on a fast idle machine; more on a loaded one): no test counts on it.
"""

from __future__ import annotations

import queue
import re
import textwrap
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.helpers import alsa_file_devices, skip_unless_portaudio, wait_until

skip_unless_portaudio()

from actors import ActorSystem  # noqa: E402
from actors.topics import Publisher, Subscription  # noqa: E402
from embagents.components import HealthStatus  # noqa: E402
from embagents.models.actor import ModelActor  # noqa: E402
from embagents.models.files.speech import SPEECH_CLIP_WORDS  # noqa: E402
from embagents.msgs import Audio  # noqa: E402
from embagents.requests import Call, HealthQuery, Reconfigure  # noqa: E402
from embagents.runtime.component_actor import ComponentActor  # noqa: E402
from embagents.system import load_system, remember_system  # noqa: E402

SYSTEM = '''
from embagents.components import Microphone, MicrophoneConfig, Speaker, SpeakerConfig, SpeechToText, SpeechToTextConfig
from embagents.models import LocalModelClient
from embagents.msgs import Audio, String
from embagents.system import System
from embagents.topic import Topic

mic = Topic("mic", Audio, queue_size=1000, keep="all")
heard = Topic("heard", String, keep="all")
said = Topic("said", Audio, queue_size=1000, keep="all")
system = System([
    Microphone(name="mic", outputs=[mic], config=MicrophoneConfig(device="robotmic", retry_s=0.2, retry_max_s=0.4)),
    SpeechToText(name="ears", inputs=[mic], outputs=[heard], model_client=LocalModelClient("whisper"),
                 config=SpeechToTextConfig(min_silence_ms=300)),
    Speaker(name="speaker", inputs=[said], config=SpeakerConfig(device=SPEAKER, sample_rate=16000, channels=1,
                                                                retry_s=0.2, retry_max_s=0.4)),
], external=[said])
'''


def words(text: str) -> str:
    return " ".join(re.findall(r"[a-z']+", text.lower()))


@pytest.fixture
def devices(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A folder with the ALSA config of robotmic and robotspeaker; the actor processes started after see them."""
    monkeypatch.setenv("ALSA_CONFIG_PATH", alsa_file_devices(tmp_path))
    return tmp_path


def write_mic_input(folder: Path, clip: np.ndarray) -> None:
    # Silence after the clip ends the last phrase; past the file's end the null PCM repeats its last buffer (silence).
    np.concatenate([clip, np.zeros(3 * 16000, np.int16)]).astype("<i2").tofile(folder / "mic.raw")


def start(asys: ActorSystem, folder: Path, *names: str, speaker: str = "robotspeaker") -> None:
    path = str(folder / "system.py")
    Path(path).write_text(textwrap.dedent(SYSTEM).replace("SPEAKER", repr(speaker)))
    remember_system(path, load_system(path))
    for name in names:
        asys.spawn(ComponentActor, name, path, name, wait=30)


def health(asys: ActorSystem, name: str) -> dict[str, Any]:
    return dict(asys.ref(name).ask(HealthQuery(), timeout=5).get())


def collect(asys: ActorSystem, topic: str) -> queue.Queue[Any]:
    got: queue.Queue[Any] = queue.Queue()
    asys.rt.on_client(lambda: Subscription(asys.rt, asys.loop, topic, got.put, queue_size=1000, keep="all"))
    return got


def played(folder: Path) -> np.ndarray:
    """What robotspeaker has written so far (ALSA's file plugin writes it a period at a time)."""
    path = folder / "speaker.raw"
    return np.fromfile(path, "<i2") if path.is_file() else np.zeros(0, np.int16)


def cpu_s(pid: int) -> float:
    import psutil

    t = psutil.Process(pid).cpu_times()
    return float(t.user + t.system)


def speaker_connected(asys: ActorSystem, devices: Path) -> tuple[Callable[[Audio], None], Callable[[], dict[str, Any]]]:
    """Start the speaker; ``(send, stats)`` once its subscription is connected."""
    start(asys, devices, "speaker")
    pub = asys.rt.on_client(lambda: Publisher(asys.rt, "said"))

    def send(msg: Audio) -> None:
        asys.rt.on_client(lambda: pub.publish(msg))

    def stats() -> dict[str, Any]:
        return dict(asys.ref("speaker").ask(Call("stats"), timeout=5).get())

    # An empty Audio ends an utterance: sent until one has arrived, so the subscription is connected.
    wait_until(lambda: stats()["utterances"] >= 1, 10, "the speaker's subscription", interval=0.2,
               poke=lambda: send(Audio(data=np.zeros(0, np.int16))))
    return send, stats


def test_the_speaker_plays_exactly_the_samples_it_got_and_converts_other_formats(devices: Path) -> None:
    tone = (8000 * np.sin(np.arange(8000) / 7)).astype(np.int16)
    tone[tone == 0] = 1  # no silent sample: what the file holds besides the tone must be nothing
    with ActorSystem() as asys:
        send, stats = speaker_connected(asys, devices)
        for i in range(0, tone.size, 1600):  # 100 ms chunks, then the end of the utterance
            send(Audio(data=tone[i:i + 1600], sample_rate=16000))
        send(Audio(data=np.zeros(0, np.int16)))
        wait_until(lambda: played(devices).size >= tone.size, 10, "the tone played")
        written = played(devices)
        assert np.array_equal(written, tone), f"{written.size} samples written, {tone.size} sent"
        # TextToSpeech's format (float32 at 22.05 kHz, mono): resampled to the device's 16 kHz.
        voice = (0.25 * np.sin(np.arange(22050) / 5)).astype(np.float32)
        send(Audio(data=voice, sample_rate=22050))
        send(Audio(data=np.zeros(0, np.float32), sample_rate=22050))
        wait_until(lambda: played(devices).size >= tone.size + 16000, 10, "the voice played")
        written = played(devices)
        assert written.size == tone.size + 16000 and stats()["played_s"] == pytest.approx(1.5)
        assert abs(np.abs(written[tone.size:].astype(np.float32)).max() / 32767 - 0.25) < 0.01
        wait_until(lambda: not stats()["queued_s"], 5, "the queue empty")
        assert health(asys, "speaker")["status"] == HealthStatus.HEALTHY


def test_a_microphone_that_is_not_there_is_reported_retried_and_heard_once_it_appears(
        devices: Path, speech_clip: tuple) -> None:
    with ActorSystem() as asys:
        start(asys, devices, "mic")
        pid = asys.procs["mic"].pid
        failing = wait_until(lambda: (h := health(asys, "mic"))["status"] == HealthStatus.SYSTEM_FAILURE and h, 10,
                             "the missing microphone reported")
        assert "microphone 'robotmic' is not there" in failing["text"] and "python -m sounddevice" in failing["text"]
        assert "group 'audio'" in failing["text"] and "retrying in" in failing["text"]
        # It waits between tries (0.2 s doubling to 0.4 s) in the same process, using almost no CPU.
        before = cpu_s(pid)
        time.sleep(2.0)
        assert cpu_s(pid) - before < 0.2, "a waiting microphone must not spin"
        assert asys.procs["mic"].pid == pid and not asys.procs["mic"].exited.is_set()
        chunks = collect(asys, "mic")
        write_mic_input(devices, speech_clip[0])  # the device appears
        wait_until(lambda: health(asys, "mic")["status"] == HealthStatus.HEALTHY, 10, "the microphone back")
        first = chunks.get(timeout=10)
        assert first.sample_rate == 16000 and first.data.dtype == np.int16 and first.data.size == 1600
        assert asys.procs["mic"].pid == pid


def test_a_speaker_that_is_not_there_is_reported_and_a_reconfigure_to_one_that_is_recovers(devices: Path) -> None:
    with ActorSystem() as asys:
        start(asys, devices, "speaker", speaker="nospeaker")
        failing = wait_until(lambda: (h := health(asys, "speaker"))["status"] == HealthStatus.SYSTEM_FAILURE and h,
                             10, "the missing speaker reported")
        assert "speaker 'nospeaker' is not there" in failing["text"] and "aplay -l" in failing["text"]
        pid = asys.procs["speaker"].pid
        before = cpu_s(pid)
        time.sleep(1.5)
        assert cpu_s(pid) - before < 0.15, "a waiting speaker must not spin"
        asys.ref("speaker").ask(Reconfigure({"device": "robotspeaker"}), timeout=5).get()
        wait_until(lambda: health(asys, "speaker")["status"] == HealthStatus.HEALTHY, 10, "the speaker back")
        assert asys.procs["speaker"].pid == pid and not asys.procs["speaker"].exited.is_set()


def test_audio_of_a_wrong_dtype_is_a_named_skip_and_the_next_is_played(devices: Path) -> None:
    with ActorSystem() as asys:
        start(asys, devices, "speaker")
        pub = asys.rt.on_client(lambda: Publisher(asys.rt, "said"))

        def send(msg: Audio) -> None:
            asys.rt.on_client(lambda: pub.publish(msg))

        wait_until(lambda: health(asys, "speaker")["status"] == HealthStatus.ALGORITHM_FAILURE, 10,
                   "the float64 audio refused", interval=0.2, poke=lambda: send(Audio(data=np.ones(160, np.float64))))
        text = health(asys, "speaker")["text"]
        assert text.startswith("skipped Audio: Audio.data has dtype float64; send int16 PCM or float32"), text
        send(Audio(data=np.full(1600, 1000, np.int16)))
        wait_until(lambda: played(devices).size >= 1600, 10, "the int16 audio played")
        written = played(devices)
        assert np.array_equal(written, np.full(1600, 1000, np.int16))
        assert health(asys, "speaker")["status"] == HealthStatus.HEALTHY



def test_stop_playback_drops_what_is_queued_and_the_speaker_plays_on_after_it(devices: Path) -> None:
    with ActorSystem() as asys:
        send, stats = speaker_connected(asys, devices)
        send(Audio(data=np.full(160000, 500, np.int16)))  # 10 s: the device takes 0.2 s of it per 0.1 s
        wait_until(lambda: stats()["played_s"] > 0, 10, "playing")
        dropped = asys.ref("speaker").ask(Call("stop_playback"), timeout=5).get()
        assert 5.0 < dropped < 10.0
        size = played(devices).size
        time.sleep(0.5)
        assert played(devices).size == size < 80000, "nothing more is played after the stop"
        send(Audio(data=np.full(1600, -700, np.int16)))
        wait_until(lambda: played(devices).size >= size + 1600, 10, "the next audio played")
        assert np.array_equal(played(devices)[size:], np.full(1600, -700, np.int16))


def test_input_device_present_says_whether_portaudio_finds_the_microphone(devices: Path, speech_clip: tuple) -> None:
    import subprocess
    import sys

    def present(device: str) -> str:
        code = f"from embagents.components.audio_devices import input_device_present as p; print(p({device!r}))"
        return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60).stdout.strip()

    assert present("robotmic") == "False"  # its input file is not there yet: ALSA cannot open it
    write_mic_input(devices, speech_clip[0])
    assert present("robotmic") == "True" and present("nomic") == "False"


def test_the_microphone_hears_the_clip_and_speech_to_text_gets_its_words(
        devices: Path, whisper_dir: str, speech_clip: tuple) -> None:
    write_mic_input(devices, speech_clip[0])
    with ActorSystem() as asys:
        asys.spawn(ModelActor, "whisper", "stt", whisper_dir, {"threads": 1}, True, wait=60)
        heard = collect(asys, "heard")
        start(asys, devices, "ears", "mic")
        phrases = [words(heard.get(timeout=30).data)]
        while " ".join(phrases) != SPEECH_CLIP_WORDS and len(phrases) < 8:
            phrases.append(words(heard.get(timeout=30).data))
        assert " ".join(phrases) == SPEECH_CLIP_WORDS
        assert health(asys, "mic")["status"] == HealthStatus.HEALTHY
        # The whole clip, 10 s in 100 ms chunks, with nothing lost: waited for, as how far the microphone has
        # read when the last phrase is heard depends on how fast Whisper is (the module's docstring).
        stats = wait_until(lambda: (s := asys.ref("mic").ask(Call("stats"), timeout=5).get())["chunks"] >= 100 and s,
                           30, "the clip's 100 chunks published", interval=0.1)
        assert stats["open"] and stats["overflows"] == 0, stats


def test_the_speaker_publishes_what_it_plays_stamped_and_a_pause_holds_the_rest_until_resume(devices: Path) -> None:
    with ActorSystem() as asys:
        path = str(devices / "system.py")
        Path(path).write_text(textwrap.dedent(SYSTEM).replace("SPEAKER", repr("robotspeaker")).replace(
            'Speaker(name="speaker", inputs=[said],',
            'Speaker(name="speaker", inputs=[said], outputs=[Topic("played", Audio, queue_size=1000, keep="all"), '
            'Topic("stages", VoiceStage, keep="all")],').replace(
            "from embagents.msgs import Audio, String", "from embagents.msgs import Audio, String, VoiceStage"))
        remember_system(path, load_system(path))
        got = collect(asys, "played")
        stages = collect(asys, "stages")
        asys.spawn(ComponentActor, "speaker", path, "speaker", wait=30)
        pub = asys.rt.on_client(lambda: Publisher(asys.rt, "said"))

        def stats() -> dict[str, Any]:
            return dict(asys.ref("speaker").ask(Call("stats"), timeout=5).get())

        wait_until(lambda: stats()["utterances"] >= 1, 10, "the speaker's subscription", interval=0.2,
                   poke=lambda: asys.rt.on_client(lambda: pub.publish(Audio(data=np.zeros(0, np.int16)))))
        sent = (np.arange(160000) % 20000).astype(np.int16)  # 10 s the device takes 0.2 s of per 0.1 s
        before = time.time()
        asys.rt.on_client(lambda: pub.publish(Audio(data=sent)))
        wait_until(lambda: stats()["played_s"] > 0.5, 10, "playing")
        held = asys.ref("speaker").ask(Call("pause"), timeout=5).get()
        assert 5.0 < held < 10.0
        size = played(devices).size
        time.sleep(0.5)
        assert played(devices).size == size, "nothing is played while paused"
        chunks: list[Any] = []
        while not got.empty():
            chunks.append(got.get())
        assert chunks[-1].data.size == 0, "a pause says on the played stream that nothing plays from then on"
        sound = [c for c in chunks if c.data.size]
        stamps = [c.stamp for c in sound]
        assert stamps == sorted(stamps) and before <= stamps[0] < before + 5
        assert np.array_equal(np.concatenate([c.data for c in sound]), sent[:sum(c.data.size for c in sound)])
        # The voice stage: the utterance's first sound given to the device, stamped with when it is heard (once).
        start = stages.get(timeout=5)
        assert (start.stage, start.source, start.stamp) == ("speaker_start", "speaker", stamps[0])
        # (ALSA's null device does not pace: what was written counts as held, as the device's buffer would)
        assert 0 < asys.ref("speaker").ask(Call("resume"), timeout=5).get() <= held
        wait_until(lambda: played(devices).size >= size + 16000, 30, "the rest played after resume")
        assert stages.empty(), "a resume plays on the same utterance: no second speaker_start"
