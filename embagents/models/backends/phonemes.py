"""Text to IPA phonemes with espeak-ng, as Piper voices were trained on.

sherpa-onnx 2.x no longer phonemizes: a Piper/VITS voice takes phoneme
codepoints. They come from espeak-ng's own library, shipped by PyPI's
``espeakng-loader`` wheel (``libespeak-ng.so`` and its data), loaded with
ctypes. espeak-ng is GPL-3.0: this module is imported only by the
text-to-speech model actor's process (never by a component), and only when
a Piper voice is served.

Text is cut into sentences (the unit that is synthesized and streamed) and
clauses; each clause's phonemes are followed by its punctuation, which Piper
voices use for pauses and intonation.

Example::

    >>> phonemize("Hello robot. Where is the cup?")                       # doctest: +SKIP
    ['həlˈoʊ ɹˈoʊbɑːt.', 'wˈɛɹ ɪz ðə kˈʌp?']
"""

from __future__ import annotations

import ctypes
import os
import re
import threading
from typing import Any

from embagents.models.sentences import split_sentences

__all__ = ["PhonemizerError", "phonemize", "split_sentences"]

_CLAUSE = re.compile(r"[^,:.!?;]+[,:.!?;]*")
_CHARS_UTF8, _PHONEMES_IPA, _OUTPUT_SYNCHRONOUS, _DONT_EXIT = 1, 0x02, 0x02, 0x8000
_lock = threading.Lock()  # espeak-ng keeps one global state per process
_lib: Any = None
_voice: str | None = None


class PhonemizerError(RuntimeError):
    """espeak-ng could not be loaded or does not know a voice (the message says how to fix it)."""


def _load() -> Any:
    global _lib
    if _lib is None:
        try:
            import espeakng_loader
        except ImportError as exc:
            raise PhonemizerError("Piper voices need espeak-ng's phonemes: pip install espeakng-loader "
                                  "(or install embagents' speech extra: pip install -e '.[speech]')") from exc
        lib = ctypes.cdll.LoadLibrary(espeakng_loader.get_library_path())
        lib.espeak_Initialize.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_char_p, ctypes.c_int]
        lib.espeak_SetVoiceByName.argtypes = [ctypes.c_char_p]
        lib.espeak_TextToPhonemes.restype = ctypes.c_char_p
        lib.espeak_TextToPhonemes.argtypes = [ctypes.POINTER(ctypes.c_void_p), ctypes.c_int, ctypes.c_int]
        data = os.path.dirname(espeakng_loader.get_data_path())  # the folder that holds espeak-ng-data/
        if lib.espeak_Initialize(_OUTPUT_SYNCHRONOUS, 0, data.encode(), _DONT_EXIT) <= 0:
            raise PhonemizerError(f"espeak-ng did not start with its data in {data!r}; reinstall espeakng-loader")
        _lib = lib
    return _lib


def _set_voice(lib: Any, voice: str) -> None:
    global _voice
    if voice != _voice:
        if lib.espeak_SetVoiceByName(voice.encode()) != 0:
            raise PhonemizerError(f"espeak-ng has no voice {voice!r}; use a language code such as 'en-us' "
                                  "(the 'espeak.voice' of the Piper voice's .onnx.json)")
        _voice = voice


def _clause(lib: Any, text: str) -> str:
    buf = ctypes.create_string_buffer(text.encode())
    ptr = ctypes.c_void_p(ctypes.addressof(buf))
    out = []
    while ptr.value:
        got = lib.espeak_TextToPhonemes(ctypes.byref(ptr), _CHARS_UTF8, _PHONEMES_IPA)
        if got:
            out.append(got.decode())
    return " ".join(p.strip() for p in out if p.strip())


def phonemize(text: str, voice: str = "en-us") -> list[str]:
    """IPA phonemes of each sentence of ``text`` (sentences with nothing to say are left out)."""
    lib = _load()
    sentences = []
    with _lock:
        _set_voice(lib, voice)
        for sentence in split_sentences(text):
            parts = []
            for clause in _CLAUSE.findall(sentence):
                words = clause.rstrip(",:.!?; ")
                marks = clause[len(words):].strip()[:1]
                said = _clause(lib, words) if words.strip() else ""
                if said:
                    parts.append(said + marks)
            if parts:
                sentences.append(" ".join(parts))
    return sentences
