"""The text end-of-turn check (LiveKit's): SmolLM2-135M-Instruct's end-of-turn token after the user's words.

The threshold (``SpeechToTextConfig.text_turn_threshold``, 4e-8) was picked on the 30 complete and 30
cut-off sentences below (written for this, none of them the bench's): the cut-offs' probabilities
were 1e-12 to 2.2e-8 but for two that can end a sentence ("Who left the door", 1.8e-4; "Could you
put the plates in", 5.1e-7), the complete ones 6.7e-8 ("Stop.") to 0.11: the threshold sits at the
geometric middle of that gap. The bench's 40 sentences (its 20 questions and their 20 first halves)
check it on sentences it was not picked on.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

pytest.importorskip("llama_cpp", reason="llama-cpp-python not installed (pip install 'embagents[llm]')")

from embagents.bench.cases_voice_turns import QUESTIONS, SPLIT_QUESTIONS  # noqa: E402
from embagents.components import SpeechToTextConfig  # noqa: E402
from embagents.models.backends.llama import LlamaBackend  # noqa: E402
from embagents.models.files.hub import default_llm_path  # noqa: E402

THRESHOLD = SpeechToTextConfig().text_turn_threshold

#: The sentences the threshold was picked on (not the bench's).
COMPLETE = (
    "Stop.", "Thank you.", "Come here.", "What time is it?", "Turn left.", "Yes, please.",
    "Where is the remote control?", "Can you clean the table?", "Pick up the green ball.",
    "Open the fridge door.", "How old are you?", "Who is at the front door?",
    "Please close the curtains.", "Is it going to rain tomorrow?", "Bring me a glass of water.",
    "What is your name?", "Put the book back on the shelf.", "Follow me to the garage.",
    "How far is the station from here?", "Show me the pictures from yesterday.",
    "Can you help me carry these bags?", "Switch off the television.", "Did anyone call while I was out?",
    "Read me the last message.", "Where are my shoes?", "Wake me up at seven.",
    "What should I cook for dinner?", "Go back to your charger.", "Is the oven still on?",
    "Hand me the scissors, please.",
)
CUT_OFF = (
    "Can you take the", "I would like a cup of", "Where is the", "Please go to the", "What is the name of",
    "Could you put the plates in", "Tell me how to", "I need you to", "Is there a", "Bring the laundry to",
    "How do I", "Can you remind me about the", "Put the keys next to", "What did you do with",
    "Show me where the", "Turn the heating up to", "Who left the door", "Do you know if", "Go and check whether the",
    "Please hand me my", "Find the charger for", "When does the shop on", "Why is the light in", "Call my brother and",
    "Can you tell me what", "Put the milk in the", "I want to watch a", "Take the dog for a", "Read the recipe for",
    "Is it cold in",
)
#: Cut-offs where a sentence can end too: the two the threshold lets through.
CAN_END = ("Could you put the plates in", "Who left the door")


@pytest.fixture(scope="module")
def llm() -> Iterator[LlamaBackend]:
    backend = LlamaBackend(default_llm_path(), n_ctx=512, n_threads=1)
    backend.load()
    yield backend
    backend.close()


def test_the_text_check_tells_the_sentences_it_was_tuned_on_apart_but_two_that_can_end_there(
        llm: LlamaBackend) -> None:
    complete = {t: llm.end_of_turn_probability(t) for t in COMPLETE}
    cut = {t: llm.end_of_turn_probability(t) for t in CUT_OFF}
    assert all(p >= THRESHOLD for p in complete.values()), {t: p for t, p in complete.items() if p < THRESHOLD}
    assert {t for t, p in cut.items() if p >= THRESHOLD} == set(CAN_END), cut


def test_the_text_check_says_the_benchs_half_questions_go_on_and_its_questions_are_finished(
        llm: LlamaBackend) -> None:
    """Sentences the threshold was not picked on."""
    halves = {first: llm.end_of_turn_probability(first) for first, _ in SPLIT_QUESTIONS}
    questions = {q: llm.end_of_turn_probability(q) for q in QUESTIONS}
    assert max(halves.values()) < THRESHOLD, halves
    assert min(questions.values()) >= THRESHOLD, questions


def test_the_text_check_reads_words_not_case_or_punctuation_and_keeps_the_system_prefix_cached(
        llm: LlamaBackend) -> None:
    p = llm.end_of_turn_probability("Where did you put my keys this morning?")
    assert llm.end_of_turn_probability("where did you put my keys, this morning") == pytest.approx(p, rel=1e-3)
    # A chat in between does not change the answer (the cache is matched token by token).
    llm.chat([{"role": "user", "content": "Hi"}], max_tokens=2)
    assert llm.end_of_turn_probability("WHERE did you put my keys this morning...") == pytest.approx(p, rel=1e-3)
