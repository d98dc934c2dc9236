"""WAV file source and sink: a file played as a microphone would, utterances written one file each."""

from __future__ import annotations

import wave
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from embagents.components import (
    WavFileSink,
    WavFileSinkConfig,
    WavFileSource,
    WavFileSourceConfig,
    read_wav,
)
from embagents.msgs import Audio, String
from embagents.topic import Topic


def write_wav(path: Path, samples: np.ndarray, rate: int = 16000, channels: int = 1) -> str:
    with wave.open(str(path), "wb") as w:
        w.setnchannels(channels)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(samples.astype("<i2").tobytes())
    return str(path)


def test_the_source_plays_the_file_in_chunks_then_marks_the_end(tmp_path: Path) -> None:
    samples = (np.arange(4000) % 300).astype(np.int16)
    src = WavFileSource(name="mic", outputs=[Topic("mic", Audio, keep="all")],
                        config=WavFileSourceConfig(path=write_wav(tmp_path / "a.wav", samples), chunk_ms=100))
    sent: list[Audio] = []
    src.attach(lambda topic, msg: sent.append(msg))
    src.on_configure()
    for _ in range(8):
        src.execute()
    assert [a.data.size for a in sent] == [1600, 1600, 800, 0], "three chunks, then one end-of-stream marker"
    assert np.array_equal(np.concatenate([a.data for a in sent]), samples)


def test_the_sink_writes_one_file_per_utterance_and_names_it(tmp_path: Path) -> None:
    sink = WavFileSink(name="out", inputs=[Topic("speaker", Audio, keep="all")], outputs=[Topic("written", String)],
                       config=WavFileSinkConfig(folder=str(tmp_path / "said"), prefix="answer"))
    sent: list[Any] = []
    sink.attach(lambda topic, msg: sent.append(msg))
    tone = (0.5 * np.sin(np.arange(2205) / 10)).astype(np.float32)
    for msg in [Audio(data=tone, sample_rate=22050), Audio(data=tone, sample_rate=22050), Audio(data=np.zeros(0, np.float32)),
                Audio(data=np.ones(100, np.float64)), Audio(data=np.zeros(160, np.int16)), Audio(data=np.zeros(0, np.int16))]:
        sink.on_message("speaker", msg)
    sink.execute()
    paths = [m.data for m in sent]
    assert paths == [str(tmp_path / "said" / "answer-1.wav"), str(tmp_path / "said" / "answer-2.wav")]
    first, rate, channels = read_wav(paths[0])
    assert (rate, channels, first.size) == (22050, 1, 4410)
    assert "bad audio dtype float64" in sink.health.text, "the float64 chunk was skipped, named, and the rest kept"


def test_a_missing_or_wrong_wav_file_is_named_with_the_fix(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="WAV file not found.*nope.wav"):
        read_wav(str(tmp_path / "nope.wav"))
    (tmp_path / "x.wav").write_bytes(b"not a wav")
    with pytest.raises(ValueError, match="not a PCM WAV file.*convert it"):
        read_wav(str(tmp_path / "x.wav"))
