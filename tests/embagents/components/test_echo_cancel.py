"""Echo cancellation on real audio made offline: the robot's Piper voice through a simulated room, then the user.

The WAV source plays a clip in which the microphone first hears the robot's
own answer (its echo: a delay and a room impulse response) and then the user
asking something; the reference is what the robot's speaker played, stamped
as the Speaker stamps it. Silero VAD and Whisper (both real, in this process)
then say what reached the recognizer.
"""

from __future__ import annotations

import time
import wave
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("sherpa_onnx")
pytest.importorskip("livekit")

from embagents.bench.echo_room import echo_of, mix_at, robot_says, room_impulse_response, to_int16  # noqa: E402
from embagents.components import WavFileSource, WavFileSourceConfig  # noqa: E402
from embagents.components.echo_cancel import EchoCanceller, erle_db  # noqa: E402
from embagents.msgs import Audio  # noqa: E402
from embagents.topic import Topic  # noqa: E402

RATE = 16000
ROBOT = "The red cup is on the kitchen table, next to the blue plate and the bread."
USER = "Please bring me the green bottle."


def write_wav(path: Path, samples: np.ndarray) -> str:
    with wave.open(str(path), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(RATE)
        w.writeframes(samples.astype("<i2").tobytes())
    return str(path)


@pytest.fixture(scope="module")
def clip() -> tuple[np.ndarray, np.ndarray]:
    """``(played, mic)``: the robot's answer as played, and the microphone: its echo, then the user's question."""
    played = np.concatenate([robot_says(ROBOT), np.zeros(4 * RATE, np.int16)])
    echo = echo_of(played, room_impulse_response(RATE, delay_ms=35, rt60_s=0.3, seed=3), level_db=-24.0)
    user_at = len(played) - 3 * RATE
    mic = mix_at(echo, robot_says(USER), user_at, level_db=-26.0)
    mic += np.random.default_rng(0).standard_normal(len(mic)) * 10 ** (-65 / 20)
    return played, to_int16(mic)


class _Clock:
    """Wall time that moves only when the test says: a stall of the test process (a loaded machine) does not
    shift the speaker's stream against the microphone's chunks, as it would with ``time.time``."""

    def __init__(self) -> None:
        self.now = 1_700_000_000.0

    def time(self) -> float:
        return self.now


def run_source(path: str, played: np.ndarray | None) -> np.ndarray:
    """Step a WavFileSource through the clip; with ``played``, feed it the speaker's stream as the Speaker stamps it."""
    import embagents.components.audio_io as audio_io

    clock, real = _Clock(), audio_io.time
    audio_io.time = clock  # type: ignore[assignment]  # the source stamps its chunks with it
    try:
        return _run_source(path, played, clock)
    finally:
        audio_io.time = real


def _run_source(path: str, played: np.ndarray | None, clock: _Clock) -> np.ndarray:
    inputs = [Topic("played", Audio, keep="all")] if played is not None else []
    src = WavFileSource(name="mic", inputs=inputs, outputs=[Topic("mic", Audio, keep="all")], trigger=10.0,
                        config=WavFileSourceConfig(path=path, chunk_ms=100))
    out: list[Audio] = []
    src.attach(lambda topic, msg: out.append(msg))
    src.on_configure()
    step = RATE // 10
    for at in range(0, len(src.samples) + step, step):
        clock.now += 0.1
        if played is not None and at < len(played):
            # The chunk the source publishes next ends now: its first sample was played 0.1 s ago.
            src.on_message("played", Audio(data=played[at:at + step], sample_rate=RATE, stamp=clock.now - 0.1))
        src.execute()
    assert out[-1].data.size == 0, "the end-of-stream marker comes last"
    return np.concatenate([m.data for m in out])


def utterances(samples: np.ndarray, whisper_dir: str) -> list[str]:
    """What Silero VAD cuts out of ``samples`` (as SpeechToText does), each transcribed by Whisper."""
    from embagents.components.vad import SpeechSegmenter
    from embagents.models.backends.sherpa_stt import SherpaRecognizer
    from embagents.models.files.speech import silero_vad_path

    vad = SpeechSegmenter(silero_vad_path(progress=False), min_silence_ms=500)
    x = samples.astype(np.float32) / 32768.0
    found = [u for i in range(0, len(x), 1600) for u in vad.feed(x[i:i + 1600])] + vad.flush()
    stt = SherpaRecognizer(whisper_dir, threads=1)
    return [str(stt.transcribe(u)).lower() for u in found]


def test_the_robots_own_voice_is_cancelled_before_the_vad_and_the_users_question_comes_through(
        tmp_path: Path, clip: tuple[np.ndarray, np.ndarray], whisper_dir: str) -> None:
    played, mic = clip
    path = write_wav(tmp_path / "room.wav", mic)
    heard = utterances(run_source(path, played), whisper_dir)
    assert len(heard) == 1 and "green bottle" in heard[0], heard
    # Without the speaker's stream (no echo cancellation) the recognizer gets the robot's own words too.
    heard_raw = utterances(run_source(path, None), whisper_dir)
    assert len(heard_raw) >= 2 and any("cup" in h or "table" in h for h in heard_raw), heard_raw


def test_with_no_speaker_in_the_system_the_source_publishes_the_file_unchanged(
        tmp_path: Path, clip: tuple[np.ndarray, np.ndarray]) -> None:
    _, mic = clip
    path = write_wav(tmp_path / "room.wav", mic)
    assert np.array_equal(run_source(path, None), mic)


def test_the_canceller_takes_20_db_off_the_echo_and_leaves_silence_after_the_speaker_stops() -> None:
    played = robot_says(ROBOT)
    echo = to_int16(echo_of(played, room_impulse_response(RATE, delay_ms=40, seed=5), level_db=-20.0))
    aec, t0 = EchoCanceller(RATE), 100.0
    aec.reference(played[:RATE], RATE, stamp=t0)
    aec.reference(played[RATE:], RATE, stamp=t0 + 1.0)  # announced in two pieces, as the Speaker writes it
    out = np.concatenate([aec.process(echo[i:i + 1600], stamp=t0 + (i + 1600) / RATE)
                          for i in range(0, len(echo) - 1599, 1600)])
    assert erle_db(echo[:len(out)], out) >= 20.0
    assert aec.playing(t0 + 1.0) and not aec.playing(t0 + len(played) / RATE + 0.01)
    aec.reference(np.zeros(0, np.int16), RATE, stamp=t0 + 0.5)  # the speaker paused at 0.5 s
    assert not aec.playing(t0 + 0.6)


def test_a_rate_the_webrtc_module_does_not_take_is_named_with_the_fix() -> None:
    with pytest.raises(ValueError, match="8000, 16000, 32000, 48000 Hz, got 44100 Hz; set the microphone's"):
        EchoCanceller(44100)


def test_a_speaker_paused_with_sound_announced_ahead_does_not_cancel_the_user_who_spoke_over_it(tmp_path: Path) -> None:
    # The Speaker announces what it plays ahead of time; on barge-in it pauses and says so with an empty chunk.
    # What it had announced after that is never played: cancelling it anyway ate the start of the user's words.
    robot, user = robot_says(ROBOT), robot_says(USER)
    echo = to_int16(echo_of(robot, room_impulse_response(RATE, delay_ms=35, rt60_s=0.3, seed=3), level_db=-24.0))
    user = to_int16(mix_at(np.zeros(len(user)), user, 0, level_db=-26.0))
    src = WavFileSource(name="mic", inputs=[Topic("played", Audio, keep="all")], outputs=[Topic("mic", Audio, keep="all")],
                        trigger=10.0, config=WavFileSourceConfig(path=write_wav(tmp_path / "m.wav", np.concatenate([echo, user])),
                                                                 chunk_ms=100))
    out: list[Audio] = []
    src.attach(lambda topic, msg: out.append(msg))
    src.on_configure()
    step = RATE // 10
    for at in range(0, len(echo) - step + 1, step):  # the robot speaks: the canceller converges on its echo
        src.on_message("played", Audio(data=robot[at:at + step], sample_rate=RATE, stamp=time.time() - 0.1))
        src.execute()
    heard = len(np.concatenate([m.data for m in out]))
    now = time.time()
    src.on_message("played", Audio(data=robot[:2 * RATE], sample_rate=RATE, stamp=now))  # 2 s announced...
    src.on_message("played", Audio(data=np.zeros(0, np.int16), sample_rate=RATE, stamp=now))  # ...and paused at once
    for k in range(len(user) // step):  # in real time: each chunk is stamped when it ends, after the pause
        time.sleep(max(0.0, now + (k + 1) * 0.1 - time.time()))
        src.execute()
    got = np.concatenate([m.data for m in out])[heard:]
    # Its first second (where the announced sound lay): 1 dB off with the pause heeded, 6-12 dB eaten without.
    assert erle_db(user[:RATE], got[:RATE]) < 3.0, "the user's voice came through (no more than 3 dB off)"
