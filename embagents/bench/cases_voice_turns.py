"""How the voice behaves like a person: ``aec``, ``barge_in``, ``turn_detection``.

Real audio made offline (:mod:`embagents.bench.echo_room`): the robot's own
Piper voice played through a simulated echo path (a delay and a synthetic
room impulse response), mixed with user speech from the same voice; the
ground truth (when the user starts and stops) comes from how the clip was built.

- ``aec``: 20 robot answers played through 20 rooms (delays 20-48 ms, RT60
  0.2-0.4 s, echo at -26 dBFS RMS, a -65 dBFS noise floor) into
  :class:`~embagents.components.echo_cancel.EchoCanceller` (WebRTC AEC3 from
  the livekit wheel) with the speaker's stamped reference, in one continuous
  stream. ``erle_db``: echo power in / out over all 20 (noise-free pass);
  ``vad_echo_triggers``: segments in which Silero VAD (the SpeechToText
  settings) finds speech in the cancelled echo, with ``vad_echo_triggers_without_aec``
  on the same audio uncancelled. Bars: ``erle_db`` >= 20, ``vad_echo_triggers`` == 0.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from actors import ActorSystem
from embagents.bench.echo_room import (
    ROBOT_LINES,
    USER_BACKCHANNELS,
    USER_INTERRUPTIONS,
    echo_of,
    rms_db,
    robot_says,
    room_impulse_response,
    said_with_a_pause,
    to_int16,
)
from embagents.bench.registry import BenchOptions, case
from embagents.components import SpeechToText, SpeechToTextConfig
from embagents.components.echo_cancel import EchoCanceller, erle_db
from embagents.components.vad import SpeechSegmenter
from embagents.models import LocalModelClient, TurnDetectorModel
from embagents.models.actor import ModelActor
from embagents.models.files.speech import silero_vad_path, whisper_tiny_en_dir
from embagents.msgs import Audio, BargeIn, String, VoiceStage
from embagents.topic import Topic

__all__: list[str] = []

RATE = 16000
CHUNK = 1600  # 100 ms
BARGE_CHUNK = 320  # 20 ms: a microphone at chunk_ms=20, as a voice robot that can be interrupted runs it (LiveKit: 10-20 ms)


def _echo_stream(n: int, noise_db: float | None) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """``(played, mic, echo)`` per segment: the robot's line, what the mic hears, the echo alone (float)."""

    rng = np.random.default_rng(7)
    played, mic, echo = [], [], []
    for i in range(n):
        line = robot_says(ROBOT_LINES[i % len(ROBOT_LINES)])
        line = np.concatenate([line, np.zeros(RATE, np.int16)])  # a second of silence after each answer
        h = room_impulse_response(RATE, delay_ms=20 + 1.5 * i, rt60_s=0.2 + 0.01 * i, seed=i)
        e = echo_of(line, h, level_db=-26.0)
        m = e + (rng.standard_normal(len(e)) * 10 ** (noise_db / 20) if noise_db is not None else 0.0)
        played.append(line)
        mic.append(to_int16(m))
        echo.append(e)
    return played, mic, echo


def _cancel(played: list[np.ndarray], mic: list[np.ndarray],
            took: list[float] | None = None) -> list[np.ndarray]:
    """Each segment's microphone audio through one EchoCanceller, as a Microphone runs it (100 ms chunks).

    ``took`` gets the seconds each 100 ms chunk took to cancel.
    """

    aec = EchoCanceller(RATE)
    t0, at, out = 1000.0, 0, []
    for ref, m in zip(played, mic, strict=True):
        aec.reference(ref, RATE, stamp=t0 + at / RATE)  # the speaker announces what it plays ahead of time
        seg = []
        for i in range(0, len(m), CHUNK):
            start = time.perf_counter()
            seg.append(aec.process(m[i:i + CHUNK], stamp=t0 + (at + i + CHUNK) / RATE))
            if took is not None:
                took.append(time.perf_counter() - start)
        out.append(np.concatenate(seg))
        at += len(m)
    return out


def _vad_triggers(segments: list[np.ndarray]) -> int:
    vad = SpeechSegmenter(silero_vad_path(), min_silence_ms=500, min_speech_ms=250)
    triggered = 0
    for seg in segments:
        x = seg.astype(np.float32) / 32768.0
        found = []
        for i in range(0, len(x), CHUNK):
            found += vad.feed(x[i:i + CHUNK])
        found += vad.flush()
        triggered += bool(found)
    return triggered


@case("aec", transport="embagents", kind="speech", needs="sherpa_onnx")
def aec(opts: BenchOptions) -> dict[str, Any]:
    n = 5 if opts.quick else 20
    played, mic, _ = _echo_stream(n, noise_db=None)
    took: list[float] = []
    out = _cancel(played, mic, took)
    erle = erle_db(np.concatenate(mic), np.concatenate(out))
    erle_after_first = erle_db(np.concatenate(mic[1:]), np.concatenate(out[1:]))
    played, noisy, _ = _echo_stream(n, noise_db=-65.0)
    cancelled = _cancel(played, noisy)
    with_aec, without = _vad_triggers(cancelled), _vad_triggers(noisy)
    return {
        "p50_us": float(np.percentile(took, 50)) * 1e6, "p99_us": float(np.percentile(took, 99)) * 1e6,
        "msgs_per_s": None, "erle_db": round(erle, 1), "erle_db_after_first": round(erle_after_first, 1),
        "vad_echo_triggers": with_aec, "vad_echo_triggers_without_aec": without, "segments": n,
        "note": f"the robot's Piper voice through {n} simulated rooms (20-48 ms, RT60 0.2-0.4 s, echo -26 dBFS): "
                f"ERLE {erle:.1f} dB ({erle_after_first:.1f} dB after the first answer); Silero VAD fired on "
                f"{with_aec}/{n} echo-only answers with AEC, {without}/{n} without; p50/p99 = cancelling one 100 ms "
                "chunk; bars: erle_db >= 20, "
                "vad_echo_triggers == 0",
    }


def cough(seed: int, rate: int = RATE) -> np.ndarray:
    """A synthetic cough: two bursts of band-passed noise with a fast attack (int16, about 0.35 s)."""
    from scipy.signal import butter, lfilter

    rng = np.random.default_rng(100 + seed)
    b, a = butter(2, [300 / (rate / 2), 3000 / (rate / 2)], btype="band")
    parts = []
    for dur, amp in ((0.18, 1.0), (0.12, 0.6)):
        n = int(rate * dur)
        env = np.minimum(1.0, np.arange(n) / (0.01 * rate)) * np.exp(-np.arange(n) / (0.06 * rate))
        parts += [lfilter(b, a, rng.standard_normal(n)) * env * amp, np.zeros(int(0.05 * rate))]
    x = np.concatenate(parts)
    return np.clip(x / np.abs(x).max() * 12000, -32768, 32767).astype(np.int16)


class BargeTrial:
    """One answer of the robot with the user speaking over it, through the real SpeechToText (see ``barge_in``).

    The simulated speaker plays ``line`` in chunks of ``chunk`` samples (50 ms) and publishes each as
    the Speaker does (stamped), to the ears and to the microphone's echo
    canceller; the microphone hears the echo of what was actually played
    (through ``h``) plus ``user`` from ``at_s`` and a noise floor. The clock is the
    audio's: chunk ``k`` is heard at ``t0`` plus its end; a ``pause`` stops the
    speaker from the next chunk on, ``resume`` plays on, ``interrupt`` drops the rest.
    ``stop_ms``: speech onset -> the pause published (the audio's time to the end of
    the chunk that decided, plus the wall time the ears took on that chunk).
    """

    def __init__(self, ears: Any, line: np.ndarray, user: np.ndarray, h: np.ndarray, at_s: float,
                 seed: int = 0, user_db: float = -24.0, chunk: int = BARGE_CHUNK) -> None:
        self.ears, self.line, self.user, self.h, self.at_s = ears, line, user, h, at_s
        self.seed, self.user_db, self.chunk = seed, user_db, chunk

    def run(self, t0: float, tail_s: float = 1.5) -> dict[str, Any]:
        from scipy.signal import lfilter


        rng = np.random.default_rng(self.seed)
        C = self.chunk
        self.heard: list[np.ndarray] = []  # what the ears got (after echo cancellation)
        self.early_pauses = 0
        ears, events = self.ears, []
        ears.attach(lambda topic, msg: events.append((time.perf_counter(), msg)))
        aec = EchoCanceller(RATE)
        zi = np.zeros(len(self.h) - 1)
        # The robot said something in this room before (a canceller on a robot has long converged): the line
        # once, ended 0.5 s before this answer starts.
        warm = np.concatenate([self.line, np.zeros(RATE // 2, np.int16)])
        w0 = t0 - len(warm) / RATE
        aec.reference(warm, RATE, w0)
        for k in range(0, len(warm) - C + 1, C):
            echo, zi = lfilter(self.h, [1.0], warm[k:k + C].astype(np.float64) / 32768.0 * 0.35, zi=zi)
            aec.process(to_int16(echo + rng.standard_normal(C) * 10 ** (-65 / 20)), w0 + (k + C) / RATE)
        user = self.user.astype(np.float64) / 32768.0
        user *= 10 ** ((self.user_db - rms_db(user)) / 20)
        at = int(self.at_s * RATE)
        onset = at + int(np.flatnonzero(np.abs(user) > 0.003)[0])
        total = at + len(user) + int(tail_s * RATE)
        pos, state, stop_ms, decided = 0, "playing", None, []
        for k in range(total // C):
            start = k * C
            if state == "playing" and pos < len(self.line):
                out = self.line[pos:pos + C]
                out = np.pad(out, (0, C - len(out)))
                pos += C
                ref = Audio(data=out, sample_rate=RATE, stamp=t0 + start / RATE)
                aec.reference(ref.data, RATE, ref.stamp)
                ears.on_message("played", ref)
            else:
                out = np.zeros(C, np.int16)
            echo, zi = lfilter(self.h, [1.0], out.astype(np.float64) / 32768.0 * 0.35, zi=zi)
            mic = echo + rng.standard_normal(C) * 10 ** (-65 / 20)
            lo, hi = max(start, at), min(start + C, at + len(user))
            if hi > lo:
                mic[lo - start:hi - start] += user[lo - at:hi - at]
            stamp = t0 + (start + C) / RATE
            clean = aec.process(to_int16(mic), stamp)
            self.heard.append(clean)
            began = time.perf_counter()
            events.clear()
            if ears.on_message("mic", Audio(data=clean, sample_rate=RATE, stamp=stamp)):
                ears.execute()
            for when, msg in events:
                if not isinstance(msg, BargeIn):
                    continue
                decided.append(msg.action)
                if msg.action == "pause" and start + C < onset:
                    self.early_pauses += 1  # paused by the echo, before the user said anything
                    state = "paused"
                elif msg.action == "pause" and stop_ms is None:
                    stop_ms = ((start + C - onset) / RATE + (when - began)) * 1000
                    state = "paused"
                elif msg.action == "resume":
                    state = "playing"
                elif msg.action == "interrupt":
                    state = "stopped"
            if start > at + len(user) and state == "stopped":
                break
        ears.on_message("played", Audio(data=np.zeros(0, np.int16), sample_rate=RATE, stamp=t0 + total / RATE))
        ears.on_message("mic", Audio(data=np.zeros(0, np.int16), sample_rate=RATE, stamp=t0 + total / RATE))
        ears.execute()
        return {"stop_ms": stop_ms, "actions": decided, "early_pauses": self.early_pauses, "interrupted": "interrupt" in decided,
                "heard": [m.data for _, m in events if hasattr(m, "data") and isinstance(m.data, str)]}


def barge_ears(model: str, **config: Any) -> Any:
    """The ears of the barge-in bench and tests: SpeechToText with barge-in on, as examples/voice.py wires it."""

    ears = SpeechToText(name="ears", inputs=[Topic("mic", Audio, keep="all"), Topic("played", Audio, keep="all")],
                        outputs=[Topic("heard", String), Topic("barge", BargeIn, keep="all")],
                        model_client=LocalModelClient(model),
                        config=SpeechToTextConfig(min_silence_ms=300, playback_input="played", log_level="warning",
                                                  **config))
    ears.on_configure()
    return ears


def barge_trials(n: int) -> tuple[list[BargeTrial], list[BargeTrial]]:
    """``n`` real interruptions and ``n`` backchannels and coughs over the robot's answers, in varied rooms."""

    lines = [robot_says(t) for t in ROBOT_LINES]
    talks = [robot_says(t) for t in USER_INTERRUPTIONS]
    nods = [robot_says(t) for t in USER_BACKCHANNELS]
    interrupts, backchannels = [], []
    for i in range(n):
        h = room_impulse_response(RATE, delay_ms=20 + 1.5 * i, rt60_s=0.2 + 0.01 * i, seed=i)
        at = 1.0 + 0.1 * (i % 6)
        interrupts.append(BargeTrial(None, lines[i % 5], talks[i % 5], h, at, seed=i))
        other = cough(i) if i % 4 == 3 else nods[i % 5]
        backchannels.append(BargeTrial(None, lines[(i + 2) % 5], other, h, at, seed=50 + i))
    return interrupts, backchannels


@case("barge_in", transport="embagents", kind="speech", needs="sherpa_onnx")
def barge_in(opts: BenchOptions) -> dict[str, Any]:
    n = 2 if opts.quick else 20
    interrupts, backchannels = barge_trials(n)
    stops, stopped, nod_interrupts, nod_pauses, echo_pauses = [], 0, 0, 0, 0
    with ActorSystem() as asys:
        asys.spawn(ModelActor, "bench_whisper_b", "stt", whisper_tiny_en_dir(), {"threads": 1}, True, wait=120,
                   heartbeat=None)
        t0 = time.time()
        for trial in interrupts:
            trial.ears = barge_ears("bench_whisper_b")
            got = trial.run(t0)
            t0 += 100.0
            stopped += got["interrupted"]
            echo_pauses += got["early_pauses"]
            if got["stop_ms"] is not None:
                stops.append(got["stop_ms"])
        for trial in backchannels:
            trial.ears = barge_ears("bench_whisper_b")
            got = trial.run(t0)
            t0 += 100.0
            nod_interrupts += got["interrupted"]
            echo_pauses += got["early_pauses"]
            nod_pauses += "pause" in got["actions"]
    p50 = float(np.percentile(stops, 50)) if stops else float("nan")
    p99 = float(np.percentile(stops, 99)) if stops else float("nan")
    return {
        "p50_us": p50 * 1e3, "p99_us": p99 * 1e3, "msgs_per_s": None,
        "stop_p50_ms": round(p50, 1), "interruptions_stopped": stopped, "interruptions": n,
        "backchannel_interrupts": nod_interrupts, "backchannel_pauses": nod_pauses, "backchannels": n,
        "echo_pauses": echo_pauses,
        "note": f"the robot's answers (Piper) through simulated rooms with AEC, the user's Piper voice over them: "
                f"{stopped}/{n} interruptions stopped the robot (onset -> pause p50 {p50:.0f} ms, max "
                f"{max(stops, default=float('nan')):.0f} ms); {nod_interrupts}/{n} backchannels and coughs "
                f"interrupted ({nod_pauses} paused it and resumed); the echo alone paused it {echo_pauses} times in "
                f"{2 * n} answers (resumed); bars: stop_p50_ms <= 200, "
                "interruptions_stopped == all, backchannel_interrupts == 0",
    }


#: Complete questions, and the same questions with a pause mid-sentence (after the first part; see turn_clips).
QUESTIONS = (
    "Can you bring me the red cup from the kitchen?",
    "What is the weather like in Paris today?",
    "Please turn off the lights in the living room.",
    "How long will it take to charge your battery?",
    "Where did you put my keys this morning?",
    "Could you tell me a short story about a dragon?",
    "What time does the train to Berlin leave?",
    "Go to the door and wait for me there.",
    "Is there any milk left in the fridge?",
    "Remind me to call my mother at six o'clock.",
    "Can you open the window in the bedroom?",
    "Please put the blue box on the top shelf.",
    "How many apples are left in the basket?",
    "Could you find my glasses near the sofa?",
    "What did the doctor say about my back?",
    "Turn on the music in the kitchen please.",
    "When is the package from my sister arriving?",
    "Bring the chair from the garden to the porch.",
    "Can you tell me where the scissors are?",
    "Tell me the news from this morning.",
)
SPLIT_QUESTIONS = (
    ("Can you bring me the", "red cup from the kitchen?"),
    ("What is the weather like in", "Paris today?"),
    ("Please turn off the lights in the", "living room."),
    ("How long will it take to", "charge your battery?"),
    ("Where did you put my", "keys this morning?"),
    ("Could you tell me a short story about", "a dragon?"),
    ("What time does the train to", "Berlin leave?"),
    ("Go to the door and", "wait for me there."),
    ("Is there any milk left in the", "fridge?"),
    ("Remind me to call my mother at", "six o'clock."),
    ("Can you open the", "window in the bedroom?"),
    ("Please put the blue box on the", "top shelf."),
    ("How many apples are left in", "the basket?"),
    ("Could you find my", "glasses near the sofa?"),
    ("What did the doctor say about", "my back?"),
    ("Turn on the music in", "the kitchen please."),
    ("When is the package from", "my sister arriving?"),
    ("Bring the chair from the garden to", "the porch."),
    ("Can you tell me where the", "scissors are?"),
    ("Tell me the news from", "this morning."),
)


def turn_clips(n: int) -> list[tuple[np.ndarray, int, bool]]:
    """``(clip, speech_end, split)``: ``n`` complete questions and ``n`` with a 500-800 ms pause mid-sentence.

    A paused question is the whole question spoken in one go, cut between two
    words (:func:`~embagents.bench.echo_room.said_with_a_pause`): spoken as two
    sentences, its first part would end on the voice's final fall, which any
    turn model hears as a finished utterance.
    """

    clips = []
    for i in range(n):
        q = robot_says(QUESTIONS[i % len(QUESTIONS)])
        clips.append((np.concatenate([np.zeros(RATE // 2, np.int16), q, np.zeros(2 * RATE, np.int16)]),
                      RATE // 2 + len(q), False))
    for i in range(n):
        said, _ = said_with_a_pause(*SPLIT_QUESTIONS[i % len(SPLIT_QUESTIONS)], 0.5 + 0.3 * i / max(1, n - 1))
        speech = np.concatenate([np.zeros(RATE // 2, np.int16), said])
        clips.append((np.concatenate([speech, np.zeros(2 * RATE, np.int16)]), len(speech), True))
    return clips


#: The higher turn threshold the bench runs beside the default (0.5, Pipecat's).
STRICT = 0.9


class _Asked:
    """The turn model's client, keeping each probability it answered (the bench reports the first per clip)."""

    def __init__(self, client: Any) -> None:
        self.client = client
        self.probabilities: list[float] = []

    def end_of_turn(self, audio: Any) -> dict[str, Any]:
        got = dict(self.client.end_of_turn(audio))
        self.probabilities.append(float(got["probability"]))
        return got


def turn_run(ears: Any, clip: np.ndarray, t0: float, speech_end: int | None = None,
             to_transcript: list[float] | None = None, texts: list[str] | None = None) -> tuple[int, float | None]:
    """Feed ``clip`` in 20 ms chunks; ``(utterances heard, end of turn delay in s of the first)``.

    The delay is the ears' own ``eou_delay``; with ``speech_end`` (the sample where the speech
    ended, from how the clip was built) and a ``VoiceStage`` output on ``ears``, it is measured
    from the end of speech to the end-of-turn decision on the wall clock: from 0.3 s before the
    end of speech until the turn is published, chunks come at a microphone's pace (each when its
    last sample has been said, or at once when the ears are behind), so what the ears do in the
    background meanwhile (a transcript begun at the pause) has the time it would have live.
    ``to_transcript`` gets the same delay to the transcript's publication, ``texts`` what was heard.
    """

    heard: list[float] = []
    decided: list[float] = []

    def got(topic: str, msg: Any) -> None:
        if isinstance(msg, String):
            heard.append(time.time())
            if texts is not None:
                texts.append(msg.data)
        elif isinstance(msg, VoiceStage) and msg.stage == "end_of_turn":
            decided.append(msg.stamp)

    ears.attach(got)
    delay = None
    paced_from = None if speech_end is None else max(0, speech_end - int(0.3 * RATE))
    ended_at = 0.0  # wall time the speech ended, once pacing began
    for i in range(0, len(clip), 320):
        if paced_from is not None and i >= paced_from and not heard:
            if not ended_at:
                ended_at = time.time() + (speech_end - i) / RATE  # type: ignore[operator]
            left = ended_at + (i + 320 - speech_end) / RATE - time.time()  # type: ignore[operator]
            if left > 0:
                time.sleep(left)
        if ears.on_message("mic", Audio(data=clip[i:i + 320], stamp=t0 + (i + 320) / RATE)):
            ears.execute()
        if heard and delay is None:
            if speech_end is None or not ended_at:
                delay = ears.last_eou_delay
            else:
                delay = (decided[0] if decided else heard[0]) - ended_at
                if to_transcript is not None:
                    to_transcript.append(heard[0] - ended_at)
    n = len(heard)
    ears.on_message("mic", Audio(data=np.zeros(0, np.int16), stamp=t0 + len(clip) / RATE))
    ears.execute()
    return n, delay


#: Smart Turn asked after 64 ms of pause (again 64 ms later after a no); at 0.95 or above it ends the turn
#: alone, between 0.5 and 0.95 the text check decides (SpeechToTextConfig.turn_sure_threshold).
SURE: dict[str, Any] = {"turn_sure_threshold": 0.95, "turn_silence_ms": 64.0, "turn_reask_ms": 64.0}

#: The setup the bars grade: the :data:`SURE` settings and ``speculate_after_turn=True``, with both clients.
GRADED = "model_text_sure_after"

#: The bench's turn-taking setups: (label, Smart Turn, text check, silence fallback ms, turn threshold, more config).
TURN_SETUPS: tuple[tuple[str, bool, bool, float, float, dict[str, Any]], ...] = (
    ("model", True, False, 1000.0, 0.5, {}), ("model_text", True, True, 1000.0, 0.5, {}),
    ("model_text_sure", True, True, 1000.0, 0.5, SURE),
    ("model_text_sure_after", True, True, 1000.0, 0.5, {**SURE, "speculate_after_turn": True}),
    ("text", False, True, 1000.0, 0.5, {}), ("strict", True, False, 1000.0, STRICT, {}),
    ("silence", False, False, 500.0, 0.5, {}))


@case("turn_detection", transport="embagents", kind="speech", needs="sherpa_onnx")
def turn_detection(opts: BenchOptions) -> dict[str, Any]:
    from embagents.models.files.hub import default_llm_path

    n = 1 if opts.quick else 20
    clips = turn_clips(n)
    turn = TurnDetectorModel(name="bench_turn")
    results: dict[str, dict[str, Any]] = {}
    with ActorSystem() as asys:
        asys.spawn(ModelActor, "bench_whisper_t", "stt", whisper_tiny_en_dir(), {"threads": 1}, True, wait=120,
                   heartbeat=None)
        asys.spawn(ModelActor, "bench_turn", "turn", turn.resolve(), turn.options(), True, wait=120, heartbeat=None)
        asys.spawn(ModelActor, "bench_turn_text", "llama", default_llm_path(), {"n_ctx": 512, "n_threads": 1}, True,
                   wait=300, heartbeat=None)
        for label, audio, text, silence, threshold, more in TURN_SETUPS:
            cutoffs, halves, wholes = 0, [], []
            delays: list[float] = []
            heard_delays: list[float] = []
            spec = {"used": 0, "dropped": 0}
            t0 = time.time()
            for clip, end, split in clips:
                asked = _Asked(LocalModelClient("bench_turn"))
                ears = SpeechToText(name="ears", inputs=[Topic("mic", Audio, keep="all")],
                                    outputs=[Topic("heard", String), Topic("stages", VoiceStage, keep="all")],
                                    model_client=LocalModelClient("bench_whisper_t"),
                                    turn_model_client=asked if audio else None,
                                    text_turn_client=LocalModelClient("bench_turn_text") if text else None,
                                    config=SpeechToTextConfig(min_silence_ms=silence, turn_threshold=threshold,
                                                              log_level="warning", **more))
                ears.on_configure()
                heard, delay = turn_run(ears, clip, t0, end, None if split else heard_delays)
                for k in spec:
                    spec[k] += ears.speculations[k]
                t0 += 100.0
                if split:
                    cutoffs += heard > 1
                    halves.append(asked.probabilities[0] if asked.probabilities else None)
                else:
                    wholes.append(asked.probabilities[0] if asked.probabilities else None)
                    if delay is not None:
                        delays.append(delay * 1000)
            results[label] = {"cutoffs": cutoffs, "eou_p50_ms": float(np.percentile(delays, 50)) if delays else None,
                              "eou_max_ms": max(delays, default=None), "halves": halves, "wholes": wholes,
                              "transcript_p50_ms": float(np.percentile(heard_delays, 50)) * 1000 if heard_delays
                              else None,
                              "speculations": spec}
    r = results
    m, mt, ms_, ma = r["model"], r["model_text"], r["model_text_sure"], r["model_text_sure_after"]
    said_done = sum(p is not None and p >= 0.5 for p in m["halves"])

    def ms(x: float | None) -> str:
        return "-" if x is None else f"{x:.0f} ms"

    # The graded setup is the headline (``cutoffs``, ``eou_p50_ms``: the bars): Smart Turn sure at 0.95, else the
    # text check, the transcript begun after Smart Turn's first verdict. Every setup, the graded one included, is
    # reported beside it as ``<label>_cutoffs`` etc. (``model``: Smart Turn alone, the default without a text check).
    out: dict[str, Any] = {
        "p50_us": (ma["eou_p50_ms"] or 0) * 1e3, "p99_us": (ma["eou_max_ms"] or 0) * 1e3, "msgs_per_s": None,
        "graded": GRADED, "cutoffs": ma["cutoffs"], "eou_p50_ms": ma["eou_p50_ms"],
        "transcript_p50_ms": ma["transcript_p50_ms"], "clips": 2 * n, "strict_threshold": STRICT}
    for label in r:
        out[f"{label}_cutoffs"], out[f"{label}_eou_p50_ms"] = r[label]["cutoffs"], r[label]["eou_p50_ms"]
        out[f"{label}_transcript_p50_ms"] = r[label]["transcript_p50_ms"]
    out["speculations"] = {label: r[label]["speculations"] for label in r}
    out["half_sentence_probabilities"] = [None if p is None else round(p, 2) for p in m["halves"]]
    out["question_probabilities"] = [None if p is None else round(p, 2) for p in m["wholes"]]
    out["note"] = (
        f"{n} complete spoken questions and {n} with a 500-800 ms pause mid-sentence (Piper voice; each paused one is "
        "the question spoken in one go, cut between two words); eou = end of speech (from the clip) -> the decision "
        f"(fallback: 1 s of silence); cut off / eou p50: Smart Turn alone {m['cutoffs']}/{n}, {ms(m['eou_p50_ms'])}; "
        f"Smart Turn + text check {mt['cutoffs']}/{n}, {ms(mt['eou_p50_ms'])}; Smart Turn sure at 0.95 (asked after 64 "
        f"ms), else the text check {ms_['cutoffs']}/{n}, {ms(ms_['eou_p50_ms'])} (transcript "
        f"{ms(ms_['transcript_p50_ms'])}); the same, its transcript begun after Smart Turn's first verdict "
        f"{ma['cutoffs']}/{n}, {ms(ma['eou_p50_ms'])} (transcript {ms(ma['transcript_p50_ms'])}); text check alone "
        f"{r['text']['cutoffs']}/{n}, {ms(r['text']['eou_p50_ms'])}; Smart Turn at {STRICT} {r['strict']['cutoffs']}/{n}, "
        f"{ms(r['strict']['eou_p50_ms'])}; silence at 500 ms {r['silence']['cutoffs']}/{n}, "
        f"{ms(r['silence']['eou_p50_ms'])}; Smart Turn said finished (p >= 0.5) on {said_done}/{n} half sentences at "
        "the first pause; bars (graded: the transcript after the first verdict): cutoffs <= 2, eou_p50_ms <= 300")
    return out
