"""Barge-in on real audio made offline: the robot's Piper voice through a simulated room, the user over it.

SpeechToText hears, through the echo canceller, a microphone on which the
robot's own answer plays (its echo) and the user speaks over it
(:class:`embagents.bench.cases_voice_turns.BargeTrial` builds the clip and
plays the Speaker's part: a ``pause`` stops the simulated speaker, ``resume``
plays on). Whisper runs in a real model actor. The LLM, TextToSpeech and the
Speaker's reactions to a ``BargeIn`` are tested on their own.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest

pytest.importorskip("sherpa_onnx")
pytest.importorskip("livekit")

from actors import ActorSystem  # noqa: E402
from embagents.bench.cases_voice_turns import BargeTrial, barge_ears, cough  # noqa: E402
from embagents.bench.echo_room import ROBOT_LINES, robot_says, room_impulse_response  # noqa: E402
from embagents.components import LLM, LLMConfig  # noqa: E402
from embagents.components.speech_to_text import is_backchannel  # noqa: E402
from embagents.models.actor import ModelActor
from embagents.msgs import BargeIn, StreamingString, String, VoiceStage
from embagents.topic import Topic  # noqa: E402

RATE = 16000


@pytest.fixture(scope="module")
def asys() -> Iterator[ActorSystem]:
    with ActorSystem() as running:
        yield running


@pytest.fixture(scope="module")
def whisper(asys: ActorSystem, whisper_dir: str) -> str:
    asys.spawn(ModelActor, "whisper_barge", "stt", whisper_dir, {"threads": 1}, True, wait=60)
    return "whisper_barge"


def trial(whisper: str, user: np.ndarray, seed: int = 1, **config: Any) -> dict[str, Any]:
    h = room_impulse_response(RATE, delay_ms=30, rt60_s=0.3, seed=seed)
    t = BargeTrial(barge_ears(whisper, **config), robot_says(ROBOT_LINES[1]), user, h, at_s=1.2, seed=seed)
    return t.run(time.time())


def test_the_user_speaking_over_the_robot_pauses_it_then_interrupts_and_the_question_is_heard(whisper: str) -> None:
    got = trial(whisper, robot_says("No, tell me about Berlin instead."))
    assert got["actions"][-2:] == ["pause", "interrupt"], got  # (an earlier pause by the echo resumed: counted
    assert got["interrupted"], got                               # by the bench as echo_pauses)
    assert got["stop_ms"] is not None and got["stop_ms"] < 1000, got
    assert any("berlin" in h.lower() for h in got["heard"]), got


# "Uh-huh.": the mhm-like backchannel the Piper voice says so that Whisper hears no words, or a backchannel
# (examples/voice.py's); its "Mhm." and "Mm-hmm." come back as words ("make them", "in a month") and interrupt.
@pytest.mark.parametrize("said", ["Yeah.", "Okay.", "Right.", "Uh-huh."])
def test_a_backchannel_pauses_the_robot_then_resumes_it_and_is_not_passed_on(whisper: str, said: str) -> None:
    got = trial(whisper, robot_says(said))
    assert "interrupt" not in got["actions"], got
    assert got["actions"][-1:] == ["resume"] or not got["actions"], got
    assert got["heard"] == [], got


def test_a_cough_does_not_interrupt_the_robot(whisper: str) -> None:
    got = trial(whisper, cough(0))
    assert "interrupt" not in got["actions"] and got["heard"] == [], got


def test_with_no_speaker_stream_the_same_speech_is_a_question_and_nothing_is_paused(whisper: str) -> None:
    ears = barge_ears(whisper)
    sent: list[Any] = []
    ears.attach(lambda topic, msg: sent.append(msg))
    from embagents.msgs import Audio

    x = np.concatenate([np.zeros(RATE // 2, np.int16), robot_says("No, tell me about Berlin instead."),
                        np.zeros(RATE, np.int16)])
    for i in range(0, len(x), 320):
        if ears.on_message("mic", Audio(data=x[i:i + 320], stamp=time.time())):
            ears.execute()
    assert not any(isinstance(m, BargeIn) for m in sent)
    assert any(isinstance(m, String) and "berlin" in m.data.lower() for m in sent), sent


def test_backchannels_are_told_from_words_word_by_word() -> None:
    assert is_backchannel("Yeah, okay.") and is_backchannel("Mm-hmm.") and is_backchannel("[BLANK_AUDIO]")
    # What Whisper tiny.en writes for the Piper voice's uh-huhs and hums, any case and punctuation.
    assert all(is_backchannel(t) for t in ("Uh-huh.", "ah ah ah ah", "Uh", "ah ha okay", "Ha ha ha", "HM.", "Mmhmm"))
    assert not is_backchannel("Yeah, but stop.") and not is_backchannel("Berlin")
    assert is_backchannel("sure thing", ("sure", "thing"))


def test_a_hum_whisper_spells_in_letters_is_a_backchannel_not_words() -> None:
    # The Piper voice's "Mm hm." comes back from Whisper as "M-H-M." or "M H H": three "words" that interrupted.
    from embagents.components.speech_to_text import BACKCHANNELS, _news

    assert is_backchannel("M-H-M.") and is_backchannel("M H H") and is_backchannel("Mmh.")
    assert _news("M-H-M.", BACKCHANNELS) == 0 and _news("M H H", BACKCHANNELS) == 0
    assert _news("Hm, move left.", BACKCHANNELS) == 2


# --- the LLM: an interrupt cancels the generation and marks the answer cut short -------------------


class EndlessClient:
    """Streams "word0 word1 ..." until its stream is closed (as LocalModelClient cancels in the model actor)."""

    def __init__(self) -> None:
        self.closed = 0
        self.calls: list[list[dict[str, Any]]] = []

    def chat_stream(self, messages: list[dict[str, Any]], **options: Any) -> Iterator[dict[str, Any]]:
        self.calls.append([dict(m) for m in messages])
        try:
            for i in range(10_000):
                yield {"delta": f"word{i} "}
            yield {"done": True, "finish_reason": "length", "tool_calls": None}
        finally:
            self.closed += 1


def llm_with_barge_in(client: Any) -> tuple[LLM, list[Any], list[Callable[[], None]]]:
    llm = LLM(name="llm", inputs=[Topic("heard", String), Topic("barge", BargeIn)],
              outputs=[Topic("answer", StreamingString)], model_client=client,
              config=LLMConfig(stream=True, chat_history=True))
    sent: list[Any] = []
    later: list[Callable[[], None]] = []
    llm.attach(lambda topic, msg: sent.append(msg), None, lambda delay, fn: later.append(fn))
    return llm, sent, later


def test_an_interrupt_cancels_the_generation_where_it_is_and_the_history_says_cut_short() -> None:
    client = EndlessClient()
    llm, sent, later = llm_with_barge_in(client)
    assert llm.on_message("heard", String("Tell me about Paris.")) and llm.execute()
    for _ in range(3):  # three turns of the loop: three tokens
        later.pop(0)()
    assert not llm.on_message("barge", BargeIn(action="interrupt", text="No, Berlin."))
    assert client.closed == 1, "the model's stream is closed: the model actor stops generating"
    while later:
        later.pop(0)()  # the turn scheduled before the interrupt finds nothing to do
    deltas = [m.data for m in sent if not m.done]
    assert deltas == ["word0 ", "word1 ", "word2 "] and sent[-1].done
    assert llm.history[-1] == {"role": "assistant", "content": "word0 word1 word2 ", "interrupted": True}
    assert llm.interrupted == 1
    # The next question: the model reads the cut answer as it is (no unknown key reaches it, no marker to copy).
    assert llm.on_message("heard", String("And Berlin?")) and llm.execute()
    later.pop(0)()
    assert client.calls[-1][-2] == {"role": "assistant", "content": "word0 word1 word2 "}


def test_an_interrupt_after_the_answer_was_written_marks_it_while_it_is_still_spoken() -> None:
    class Short(EndlessClient):
        def chat_stream(self, messages: list[dict[str, Any]], **options: Any) -> Iterator[dict[str, Any]]:
            yield {"delta": "Paris is big."}
            yield {"done": True, "finish_reason": "stop", "tool_calls": None}

    llm, sent, later = llm_with_barge_in(Short())
    assert llm.on_message("heard", String("Tell me about Paris.")) and llm.execute()
    while later:
        later.pop(0)()
    assert llm.history[-1] == {"role": "assistant", "content": "Paris is big."}
    llm.on_message("barge", BargeIn(action="interrupt"))
    assert llm.history[-1]["interrupted"] is True
    llm.on_message("barge", BargeIn(action="pause"))  # a pause is the Speaker's business, not the LLM's
    assert llm.interrupted == 1


def test_an_interrupt_that_comes_in_after_the_question_it_was_about_does_not_cut_that_questions_answer() -> None:
    client = EndlessClient()
    llm, sent, later = llm_with_barge_in(client)
    assert llm.on_message("heard", String("Tell me about Paris.")) and llm.execute()
    later.pop(0)()
    spoke = time.time()  # the user speaks over the answer...
    assert llm.on_message("heard", String("No, tell me about Berlin.")) and llm.execute()  # ...it is heard first
    assert llm.history[-1]["interrupted"] is True and client.closed == 1, "the question cut the first answer short"
    llm.on_message("barge", BargeIn(action="interrupt", text="No, tell", stamp=spoke))  # then the interrupt
    assert client.closed == 1 and llm.interrupted == 1, "the answer to Berlin goes on"
    later.pop(0)()
    streams = list(dict.fromkeys(m.stream_id for m in sent))
    assert len(streams) == 2 and (sent[-1].stream_id, sent[-1].data, sent[-1].done) == (streams[1], "word0 ", False)
    llm.on_message("barge", BargeIn(action="interrupt", text="Stop.", stamp=time.time()))  # speech over this one
    assert client.closed == 2 and llm.interrupted == 2


def test_an_answer_publishes_its_first_token_once_on_a_voice_stage_output() -> None:
    llm = LLM(name="llm", inputs=[Topic("heard", String), Topic("barge", BargeIn)],
              outputs=[Topic("answer", StreamingString), Topic("stages", VoiceStage)], model_client=EndlessClient(),
              config=LLMConfig(stream=True))
    sent: list[tuple[str, Any]] = []
    later: list[Callable[[], None]] = []
    llm.attach(lambda topic, msg: sent.append((topic, msg)), None, lambda delay, fn: later.append(fn))
    before = time.time()
    assert llm.on_message("heard", String("Tell me about Paris.")) and llm.execute()
    for _ in range(3):
        later.pop(0)()
    stages = [m for t, m in sent if t == "stages"]
    assert [(m.stage, m.source) for m in stages] == [("llm_first_token", "llm")] and stages[0].stamp >= before
    assert [t for t, _ in sent].index("stages") == 0, "stamped as the first token goes out"
    assert all(isinstance(m, StreamingString) for t, m in sent if t == "answer")


# --- the Speaker: an interrupt stops the sound, and the rest of that answer is not played when it comes -----


def test_a_simulated_speaker_plays_in_real_time_and_after_an_interrupt_drops_what_comes_of_that_answer() -> None:
    from embagents.components import Speaker, SpeakerConfig
    from embagents.msgs import Audio

    out: list[Audio] = []
    later: list[Callable[[], None]] = []
    speaker = Speaker(name="speaker", inputs=[Topic("said", Audio, keep="all"), Topic("barge", BargeIn)],
                      outputs=[Topic("played", Audio, keep="all")], config=SpeakerConfig(simulated=True))
    speaker.attach(lambda topic, msg: out.append(msg), None, lambda delay, fn: later.append(fn))
    speaker.on_configure()
    speaker.on_activate()  # no PortAudio, no device: it opens at once

    def send(value: int, n: int) -> None:
        assert speaker.on_message("said", Audio(data=np.full(n, value, np.int16)))
        speaker.execute()

    before = time.time()
    send(500, 2 * RATE)  # 2 s of an answer: the device takes 0.4 s ahead of the clock, the rest waits
    played = [m for m in out if m.data.size]
    assert sum(m.data.size for m in played) == int(0.4 * RATE) and before + 0.2 <= played[0].stamp < time.time() + 0.3
    assert speaker.stats()["queued_s"] == pytest.approx(1.6)
    speaker.on_message("barge", BargeIn(action="interrupt"))
    send(600, RATE // 2)  # the sentence the voice was making when the stop came: not played
    speaker.on_message("said", Audio(data=np.zeros(0, np.int16)))  # the voice ends that answer
    speaker.execute()
    send(700, RATE // 2)  # the next answer plays
    values = [int(m.data[0]) for m in out if m.data.size]
    assert set(values) == {500, 700} and values.index(700) > len(played) - 1, values
    assert out[len(played)].data.size == 0, "the stop says on the played stream that nothing plays from then on"
    assert speaker.stats()["dropped_s"] == pytest.approx(0.5)


# --- the words played: an answer cut short is kept in the LLM's history as what the user heard ---------------

ANSWER = ("Paris is the capital of France. It is known for the Eiffel Tower and its museums. "
          "Many people visit it every year.")
PLAYED_SYSTEM = '''
from embagents.components import LLM, LLMConfig, Speaker, SpeakerConfig, TextToSpeech
from embagents.models import LocalModelClient
from embagents.msgs import Audio, BargeIn, StreamingString, String
from embagents.system import System
from embagents.topic import Topic

ANSWER = WRITTEN


class Written:
    """Writes ANSWER a word per token at once: far ahead of the voice, as a model on a fast machine does."""

    def chat_stream(self, messages, **options):
        words = ANSWER.split(" ")
        for i, w in enumerate(words):
            yield {"delta": w if i == 0 else " " + w}
        yield {"done": True, "finish_reason": "stop", "tool_calls": None}


heard = Topic("heard", String, keep="all")
barge = Topic("barge", BargeIn, keep="all")
answer = Topic("answer", StreamingString, queue_size=1000, keep="all")
speaker = Topic("speaker", Audio, queue_size=1000, keep="all")
spoken = Topic("spoken", StreamingString, queue_size=1000, keep="all")  # the words the speaker played

system = System(
    [
        LLM(name="llm", inputs=[heard, barge, spoken], outputs=[answer], model_client=Written(), trigger=heard,
            config=LLMConfig(stream=True, chat_history=True)),
        TextToSpeech(name="voice", inputs=[answer, barge], outputs=[speaker], model_client=LocalModelClient("joe_played")),
        Speaker(name="speaker", inputs=[speaker, barge], outputs=[spoken], config=SpeakerConfig(simulated=True)),
    ],
    external=[heard, barge],
)
'''


def test_an_answer_interrupted_mid_playback_is_kept_in_the_history_as_the_words_played(
        asys: ActorSystem, tmp_path: Any, piper_dir: str) -> None:
    import textwrap
    from pathlib import Path

    from actors.topics import Publisher
    from embagents.requests import Call
    from embagents.runtime.component_actor import ComponentActor
    from embagents.system import load_system, remember_system
    from tests.helpers import wait_until

    path = str(tmp_path / "system.py")
    Path(path).write_text(textwrap.dedent(PLAYED_SYSTEM).replace("WRITTEN", repr(ANSWER)))
    system = load_system(path)
    remember_system(path, system)
    names = ["joe_played"] + [c.name for c in system.components]
    asys.spawn(ModelActor, "joe_played", "tts", piper_dir, {"threads": 1}, True, wait=60)
    try:
        for c in system.components:
            asys.spawn(ComponentActor, c.name, path, c.name)
        llm, speaker = asys.ref("llm"), asys.ref("speaker")
        heard = asys.rt.on_client(lambda: Publisher(asys.rt, "heard"))
        barge = asys.rt.on_client(lambda: Publisher(asys.rt, "barge"))
        asys.rt.on_client(lambda: heard.publish(String(data="Tell me about Paris.")))
        # The model wrote the whole answer long before the voice has said its first sentence.
        wait_until(lambda: speaker.ask(Call("stats"), timeout=5).get()["played_s"] >= 2.2, 60, "2 s of the answer played")
        assert llm.ask(Call("snapshot"), timeout=5).get()["history"][-1]["content"] == ANSWER
        spoke = time.time()
        asys.rt.on_client(lambda: barge.publish(BargeIn(action="pause", stamp=spoke)))  # the user speaks over it
        time.sleep(0.4)
        asys.rt.on_client(lambda: barge.publish(BargeIn(action="interrupt", text="Wait, stop.", stamp=spoke)))

        def cut() -> dict[str, Any] | None:
            last = llm.ask(Call("snapshot"), timeout=5).get()["history"][-1]
            return last if last.get("interrupted") else None

        entry = wait_until(cut, 10, "the answer marked interrupted")
        time.sleep(0.5)  # words the speaker told after the interrupt would change it: none come
        assert llm.ask(Call("snapshot"), timeout=5).get()["history"][-1] == entry
        played = speaker.ask(Call("stats"), timeout=5).get()["played_s"]
    finally:
        for name in reversed(names):
            if name in asys.procs:
                asys.stop(name)
    words, said = entry["content"].split(), ANSWER.split()
    assert entry["role"] == "assistant" and entry["interrupted"] is True
    # What the user heard: the first sentence or so, a prefix of the answer, word for word; not what was written.
    assert 3 <= len(words) < 12 and words == said[:len(words)], (entry, played)


def test_words_the_speaker_tells_after_the_interrupt_still_go_into_the_answer_cut_short() -> None:
    llm = LLM(name="llm", inputs=[Topic("heard", String), Topic("barge", BargeIn), Topic("spoken", StreamingString)],
              outputs=[Topic("answer", StreamingString)], model_client=EndlessClient(),
              config=LLMConfig(stream=True, chat_history=True))
    sent: list[Any] = []
    later: list[Callable[[], None]] = []
    llm.attach(lambda topic, msg: sent.append(msg), None, lambda delay, fn: later.append(fn))
    assert llm.on_message("heard", String("Tell me about Paris.")) and llm.execute()
    for _ in range(5):
        later.pop(0)()
    stream_id = sent[0].stream_id
    assert not llm.on_message("spoken", StreamingString(data="word0", stream_id=stream_id)), "not a question"
    llm.on_message("barge", BargeIn(action="interrupt"))
    assert llm.history[-1] == {"role": "assistant", "content": "word0", "interrupted": True}
    # The speaker stopped after the LLM heard of the interrupt: the words it played until then still come.
    llm.on_message("spoken", StreamingString(data=" word1", stream_id=stream_id))
    llm.on_message("spoken", StreamingString(data="", done=True, stream_id=stream_id))
    llm.on_message("spoken", StreamingString(data="other", stream_id="another-answer"))
    assert llm.history[-1] == {"role": "assistant", "content": "word0 word1", "interrupted": True}


def test_the_speaker_tells_the_words_as_they_are_heard_and_none_it_held_at_a_pause_or_dropped_at_a_stop() -> None:
    from embagents.components import Speaker, SpeakerConfig
    from embagents.msgs import Audio

    out: list[StreamingString] = []
    due: list[tuple[float, Callable[[], None]]] = []
    speaker = Speaker(name="speaker", inputs=[Topic("said", Audio, keep="all"), Topic("barge", BargeIn)],
                      outputs=[Topic("spoken", StreamingString, keep="all")], config=SpeakerConfig(simulated=True))
    speaker.attach(lambda topic, msg: out.append(msg), None, lambda delay, fn: due.append((time.time() + delay, fn)))
    speaker.on_configure()
    speaker.on_activate()

    def run(seconds: float) -> None:  # the component's loop, in real time: the simulated speaker plays at its pace
        end = time.time() + seconds
        while time.time() < end:
            due.sort(key=lambda d: d[0])
            if due and due[0][0] <= time.time():
                due.pop(0)[1]()
            time.sleep(0.005)

    def told(stream_id: str) -> str:
        return "".join(m.data for m in out if m.stream_id == stream_id)

    # Two sentences of 1 s each; a third chunk without text goes on with the second sentence.
    for samples, text in ((RATE, "one two three four"), (RATE // 2, "five six seven eight"), (RATE // 2, "")):
        assert speaker.on_message("said", Audio(data=np.full(samples, 300, np.int16), text=text, stream_id="a"))
        speaker.execute()
    speaker.on_message("said", Audio(data=np.zeros(0, np.int16)))
    speaker.execute()
    run(0.8)
    speaker.on_message("barge", BargeIn(action="pause"))
    at_pause = told("a").split()
    assert at_pause == "one two three four".split()[:len(at_pause)] and len(at_pause) < 4, at_pause
    run(0.3)
    assert told("a").split() == at_pause, "nothing is heard while paused"
    speaker.on_message("barge", BargeIn(action="resume"))
    run(2.5)
    assert told("a") == "one two three four five six seven eight" and out[-1] == StreamingString("", True, "a")
    # A stop: what was heard is told, then the answer is done; the rest is never told.
    speaker.on_message("said", Audio(data=np.full(2 * RATE, 300, np.int16), text="nine ten eleven twelve", stream_id="b"))
    speaker.execute()
    run(0.9)
    speaker.on_message("barge", BargeIn(action="interrupt"))
    cut = told("b").split()
    assert cut == "nine ten eleven twelve".split()[:len(cut)] and len(cut) < 4 and out[-1].done, cut
    run(0.5)
    assert told("b").split() == cut
