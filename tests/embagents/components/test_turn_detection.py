"""End of turn from Smart Turn v3 in its own model actor, on questions spoken offline by the Piper voice."""

from __future__ import annotations

import importlib.util
import time
from collections.abc import Iterator

import numpy as np
import pytest

pytest.importorskip("sherpa_onnx")
pytest.importorskip("onnxruntime")

from actors import ActorSystem  # noqa: E402
from embagents.bench.cases_voice_turns import QUESTIONS, turn_clips, turn_run  # noqa: E402
from embagents.bench.echo_room import robot_says, said_with_a_pause  # noqa: E402
from embagents.components import SpeechToText, SpeechToTextConfig  # noqa: E402
from embagents.config import ConfigError
from embagents.models import BadRequest, LocalModelClient, TurnDetectorModel  # noqa: E402
from embagents.models.actor import ModelActor
from embagents.models.backends.sherpa_stt import SherpaRecognizer
from embagents.models.files.hub import default_llm_path
from embagents.msgs import Audio, String, VoiceStage
from embagents.topic import Topic  # noqa: E402

RATE = 16000


@pytest.fixture(scope="module")
def actors(whisper_dir: str) -> Iterator[tuple[str, str]]:
    turn = TurnDetectorModel(name="turn_t")
    with ActorSystem() as asys:
        asys.spawn(ModelActor, "whisper_t", "stt", whisper_dir, {"threads": 1}, True, wait=60)
        asys.spawn(ModelActor, "turn_t", "turn", turn.resolve(), turn.options(), True, wait=60)
        if importlib.util.find_spec("llama_cpp") is not None:  # the text check (LiveKit's): a chat model
            asys.spawn(ModelActor, "turn_text_t", "llama", default_llm_path(), {"n_ctx": 512, "n_threads": 1}, True,
                       wait=120)
        yield "whisper_t", "turn_t"


def test_the_turn_model_says_a_finished_question_is_finished_and_one_trailing_off_is_not(
        actors: tuple[str, str]) -> None:
    client = LocalModelClient(actors[1])
    pause = np.zeros(RATE // 5, np.int16)  # SpeechToText asks after a short pause: the model reads it too
    done = client.end_of_turn(np.concatenate([robot_says("Where did you put my keys this morning?"), pause]))
    trailing = client.end_of_turn(np.concatenate([robot_says("What is the weather like in"), pause]))
    assert done["complete"] and done["probability"] > 0.5, done
    assert not trailing["complete"] and trailing["probability"] < 0.5, trailing


def test_audio_the_turn_model_cannot_read_is_refused_at_once_with_what_to_send(actors: tuple[str, str]) -> None:
    with pytest.raises(BadRequest, match="audio"):
        LocalModelClient(actors[1]).end_of_turn(np.zeros((2, 100), np.float32))


def ears(actors: tuple[str, str], turn: bool, min_silence_ms: float) -> SpeechToText:
    comp = SpeechToText(name="ears", inputs=[Topic("mic", Audio, keep="all")], outputs=[Topic("heard", String)],
                        model_client=LocalModelClient(actors[0]),
                        turn_model_client=LocalModelClient(actors[1]) if turn else None,
                        config=SpeechToTextConfig(min_silence_ms=min_silence_ms))
    comp.on_configure()
    return comp


def test_a_pause_mid_sentence_does_not_end_the_turn_with_the_model_and_does_with_silence_alone(
        actors: tuple[str, str]) -> None:
    a, b = robot_says("What is the weather like in"), robot_says("Paris today?")
    clip = np.concatenate([np.zeros(RATE // 2, np.int16), a, np.zeros(int(0.7 * RATE), np.int16), b,
                           np.zeros(2 * RATE, np.int16)])
    with_model = ears(actors, True, 1000.0)
    heard, _ = turn_run(with_model, clip, time.time())
    assert heard == 1 and with_model.turns["not_yet"] >= 1
    heard, _ = turn_run(ears(actors, False, 500.0), clip, time.time())
    assert heard == 2, "silence endpointing at 500 ms cuts the question at its 700 ms pause"


def test_a_finished_question_ends_the_turn_at_the_models_word_before_the_silence_fallback(
        actors: tuple[str, str]) -> None:
    clip = np.concatenate([np.zeros(RATE // 2, np.int16), robot_says("Where did you put my keys this morning?"),
                           np.zeros(2 * RATE, np.int16)])
    comp = ears(actors, True, 1500.0)
    heard, delay = turn_run(comp, clip, time.time())
    assert heard == 1 and comp.turns["model"] == 1 and comp.turns["silence"] == 0
    assert delay is not None and delay < 1.5
    stats = comp.stats()  # what `embagents call ears stats` shows
    assert stats["eou_delay"] == pytest.approx(delay * 1000, abs=0.1) and stats["transcription_delay"] > 0
    assert stats["turns"]["model"] == 1 and stats["turns"]["silence"] == 0


def test_a_turn_publishes_its_stages_on_a_voice_stage_output_as_its_stats_say(actors: tuple[str, str]) -> None:
    comp = SpeechToText(name="ears", inputs=[Topic("mic", Audio, keep="all")],
                        outputs=[Topic("heard", String), Topic("stages", VoiceStage, keep="all")],
                        model_client=LocalModelClient(actors[0]), turn_model_client=LocalModelClient(actors[1]),
                        config=SpeechToTextConfig(min_silence_ms=1500.0))
    comp.on_configure()
    sent: list[tuple[str, object]] = []
    comp.attach(lambda topic, msg: sent.append((topic, msg)))
    clip = np.concatenate([np.zeros(RATE // 2, np.int16), robot_says("Where did you put my keys this morning?"),
                           np.zeros(RATE, np.int16)])
    for i in range(0, len(clip), 320):
        if comp.on_message("mic", Audio(data=clip[i:i + 320], stamp=time.time())):
            comp.execute()
    stages = [m for t, m in sent if t == "stages"]
    assert [m.stage for m in stages] == ["end_of_speech", "end_of_turn", "transcript"], sent
    assert all(m.source == "ears" for m in stages)
    heard_at = next(i for i, (t, _) in enumerate(sent) if t == "heard")
    assert heard_at < [t for t, _ in sent].index("stages"), "the transcript goes out first: stages do not delay it"
    stats = comp.stats()
    assert (stages[1].stamp - stages[0].stamp) * 1000 == pytest.approx(stats["eou_delay"], abs=0.2)
    assert (stages[2].stamp - stages[1].stamp) * 1000 >= stats["transcription_delay"] - 0.2


def test_a_turn_threshold_above_the_models_probability_leaves_a_finished_question_to_the_silence_fallback(
        actors: tuple[str, str]) -> None:
    clip = np.concatenate([np.zeros(RATE // 2, np.int16), robot_says("Where did you put my keys this morning?"),
                           np.zeros(2 * RATE, np.int16)])
    comp = SpeechToText(name="ears", inputs=[Topic("mic", Audio, keep="all")], outputs=[Topic("heard", String)],
                        model_client=LocalModelClient(actors[0]), turn_model_client=LocalModelClient(actors[1]),
                        config=SpeechToTextConfig(min_silence_ms=1000.0, turn_threshold=0.9999))
    comp.on_configure()
    heard, _ = turn_run(comp, clip, time.time())
    p = comp.stats()["turn_probability"]
    assert heard == 1 and 0.5 < p < 0.9999, "the model says finished, at a probability under the threshold"
    assert comp.turns["not_yet"] >= 1 and comp.turns["model"] == 0 and comp.turns["silence"] == 1
    with pytest.raises(ValueError, match=r"threshold .* must be in \(0, 1\), got 1.5"):
        SpeechToTextConfig(turn_threshold=1.5)


def test_a_paused_question_the_audio_model_calls_finished_is_held_by_the_text_check_and_heard_whole(
        actors: tuple[str, str]) -> None:
    pytest.importorskip("llama_cpp")
    clip, end, split = turn_clips(1)[1]  # "Can you bring me the" (pause) "red cup from the kitchen?"
    assert split

    def ears_with(text_check: bool) -> SpeechToText:
        comp = SpeechToText(name="ears", inputs=[Topic("mic", Audio, keep="all")], outputs=[Topic("heard", String)],
                            model_client=LocalModelClient(actors[0]), turn_model_client=LocalModelClient(actors[1]),
                            text_turn_client=LocalModelClient("turn_text_t") if text_check else None,
                            config=SpeechToTextConfig(min_silence_ms=1000.0))
        comp.on_configure()
        return comp

    alone, cut = ears_with(False), []
    assert turn_run(alone, clip, time.time(), texts=cut)[0] == 2, "Smart Turn alone cuts this one off at its pause"
    assert alone.turns["model"] == 2 and "bring me" in cut[0].lower(), cut
    held, said = ears_with(True), []
    heard, _ = turn_run(held, clip, time.time(), texts=said)
    stats = held.stats()
    assert heard == 1 and stats["turns"]["text_not_yet"] == 1, (said, stats)
    assert "bring me the red" in said[0].lower() and "kitchen" in said[0].lower(), said
    assert stats["turns"]["model"] == 1 and stats["turns"]["silence"] == 0, "the whole question ended by the models"
    assert stats["text_turn_probability"] >= SpeechToTextConfig().text_turn_threshold
    # The half was transcribed at the pause (and dropped when the user went on); the whole at the last pause.
    assert stats["speculations"] == {"used": 1, "dropped": 1}


def test_a_no_from_the_turn_model_early_in_the_pause_is_asked_again_with_turn_reask_ms(
        actors: tuple[str, str]) -> None:
    # Asked after 32 ms of pause the model says "not yet" (0.13): the probability rises as the pause grows.
    clip = np.concatenate([np.zeros(RATE // 2, np.int16), robot_says("When is the package from my sister arriving?"),
                           np.zeros(2 * RATE, np.int16)])

    def ears_asking(again: float | None) -> SpeechToText:
        comp = SpeechToText(name="ears", inputs=[Topic("mic", Audio, keep="all")], outputs=[Topic("heard", String)],
                            model_client=LocalModelClient(actors[0]), turn_model_client=LocalModelClient(actors[1]),
                            config=SpeechToTextConfig(min_silence_ms=1000.0, turn_silence_ms=32.0,
                                                      turn_reask_ms=again))
        comp.on_configure()
        return comp

    once = ears_asking(None)
    assert turn_run(once, clip, time.time())[0] == 1
    assert once.turns["not_yet"] == 1 and once.turns["silence"] == 1, "one verdict per pause: the no waits for silence"
    again = ears_asking(64.0)
    assert turn_run(again, clip, time.time())[0] == 1
    assert again.turns["not_yet"] >= 1 and again.turns["model"] == 1 and again.turns["silence"] == 0, again.turns
    assert again.last_turn_probability is not None and again.last_turn_probability >= 0.5


def test_a_question_the_turn_model_is_sure_of_ends_without_waiting_for_the_text_check(
        actors: tuple[str, str]) -> None:
    pytest.importorskip("llama_cpp")
    clip = np.concatenate([np.zeros(RATE // 2, np.int16), robot_says("Where did you put my keys this morning?"),
                           np.zeros(2 * RATE, np.int16)])

    def ears_at(sure: float | None) -> SpeechToText:
        comp = SpeechToText(name="ears", inputs=[Topic("mic", Audio, keep="all")], outputs=[Topic("heard", String)],
                            model_client=LocalModelClient(actors[0]), turn_model_client=LocalModelClient(actors[1]),
                            text_turn_client=LocalModelClient("turn_text_t"),
                            config=SpeechToTextConfig(min_silence_ms=1000.0, turn_sure_threshold=sure))
        comp.on_configure()
        return comp

    checked, said = ears_at(None), []
    assert turn_run(checked, clip, time.time(), texts=said)[0] == 1
    assert checked.last_turn_probability is not None and checked.last_turn_probability >= 0.9
    assert checked.last_text_turn_probability is not None, "without a sure threshold the text check decides"
    sure, said = ears_at(0.9), []
    assert turn_run(sure, clip, time.time(), texts=said)[0] == 1
    stats = sure.stats()
    assert stats["turns"]["sure"] == 1 and stats["turns"]["model"] == 1 and stats["turns"]["silence"] == 0, stats
    assert stats["text_turn_probability"] is None, "the text check was not waited for"
    assert "keys this morning" in said[0].lower(), said
    with pytest.raises(ConfigError, match="threshold"):
        SpeechToTextConfig(turn_sure_threshold=1.2)


class _Noted:
    """A model client that notes in ``log`` when the transcript is begun and when a turn verdict comes back."""

    def __init__(self, client: LocalModelClient, log: list[str]) -> None:
        self.client, self.log = client, log

    def submit(self, *args: object, **kwargs: object) -> object:
        self.log.append("transcript")
        return self.client.submit(*args, **kwargs)  # type: ignore[arg-type]

    def end_of_turn(self, audio: object) -> dict[str, object]:
        got = self.client.end_of_turn(audio)
        self.log.append("verdict")
        return got

    def __getattr__(self, name: str) -> object:
        return getattr(self.client, name)


def test_speculate_after_turn_begins_the_transcript_after_the_pauses_first_turn_verdict(
        actors: tuple[str, str]) -> None:
    clip = np.concatenate([np.zeros(RATE // 2, np.int16), robot_says("Where did you put my keys this morning?"),
                           np.zeros(2 * RATE, np.int16)])

    def order(after: bool) -> tuple[list[str], list[str]]:
        log: list[str] = []
        said: list[str] = []
        comp = SpeechToText(name="ears", inputs=[Topic("mic", Audio, keep="all")], outputs=[Topic("heard", String)],
                            model_client=_Noted(LocalModelClient(actors[0]), log),  # type: ignore[arg-type]
                            turn_model_client=_Noted(LocalModelClient(actors[1]), log),  # type: ignore[arg-type]
                            config=SpeechToTextConfig(min_silence_ms=1000.0, turn_silence_ms=64.0,
                                                      speculate_after_turn=after))
        comp.on_configure()
        assert turn_run(comp, clip, time.time(), texts=said)[0] == 1
        return log, said

    log, said = order(False)
    assert log[:2] == ["transcript", "verdict"], log
    log, said = order(True)
    assert log[:2] == ["verdict", "transcript"], log
    assert "keys this morning" in said[0].lower(), said


def test_a_chat_model_actor_answers_the_text_check_and_refuses_audio_with_where_it_goes(
        actors: tuple[str, str]) -> None:
    pytest.importorskip("llama_cpp")
    client = LocalModelClient("turn_text_t")
    finished = client.end_of_turn_text("Can you bring me the red cup from the kitchen?")["probability"]
    going_on = client.end_of_turn_text("Can you bring me the")["probability"]
    assert going_on < SpeechToTextConfig().text_turn_threshold <= finished
    with pytest.raises(BadRequest, match="TurnDetectorModel"):
        client.infer("end_of_turn", {"audio": np.zeros(16, np.float32)})


def test_a_bench_question_with_a_pause_is_the_question_spoken_in_one_go_with_the_pause_cut_in() -> None:
    """Its words before the pause are the whole question's (a level tone), not a sentence of their own (a fall)."""
    clip, end, split = turn_clips(1)[1]
    speech, whole = clip[RATE // 2:end], robot_says(QUESTIONS[0])
    assert split and len(speech) == len(whole) + RATE // 2, "0.5 s of pause in the first paused clip"
    assert np.array_equal(speech[:RATE // 2], whole[:RATE // 2]), "the start is the whole question's"
    assert np.array_equal(speech[-RATE // 2:], whole[-RATE // 2:]), "and so is the end"


def test_the_pause_is_cut_in_between_the_two_words_it_is_said_to_fall_between(whisper_dir: str) -> None:
    stt, pad = SherpaRecognizer(whisper_dir), np.zeros(RATE // 4, np.float32)

    def words(text: str) -> list[str]:
        return "".join(c if c.isalpha() else " " for c in text.lower()).split()

    def heard(x: np.ndarray) -> list[str]:
        return words(stt.transcribe(np.concatenate([pad, x.astype(np.float32) / 32768.0, pad])))

    for first, rest in (("Go to the door and", "wait for me there."),
                        ("Is there any milk left in the", "fridge?")):
        said, cut = said_with_a_pause(first, rest, 0.6)
        assert not said[cut:cut + int(0.6 * RATE)].any()
        before, after = heard(said[:cut]), heard(said[cut + int(0.6 * RATE):])
        assert before[-1] == words(first)[-1] and after[0] == words(rest)[0], (before, after)
