"""Sentences of a text to speak: where speech synthesis cuts it, and whether a piece says anything.

Text rules shared by the TTS component (which streams an LLM's answer a
sentence at a time), the speech model actor and the OpenAI speech client;
no speech library is imported here.

Example::

    >>> split_sentences("Hi there. Shall I bring it")
    ['Hi there.', 'Shall I bring it']
    >>> speakable("...")
    False
"""

from __future__ import annotations

import re

__all__ = ["speakable", "split_sentences"]

_SENTENCE = re.compile(r"[^.!?;\n]+(?:[.!?;]+|\n|$)")


def split_sentences(text: str) -> list[str]:
    """The sentences of ``text`` (stripped, non-empty), each with its end punctuation.

    >>> split_sentences("Hi there. The cup is on the table! Shall I bring it")
    ['Hi there.', 'The cup is on the table!', 'Shall I bring it']
    """
    return [s.strip() for s in _SENTENCE.findall(text) if s.strip()]


def speakable(text: object) -> bool:
    """Whether ``text`` has anything to say (a letter or a digit).

    >>> speakable("Hello!"), speakable(" ... ?! "), speakable("")
    (True, False, False)
    """
    return isinstance(text, str) and any(ch.isalnum() for ch in text)
