"""How the voice behaves like a person: ``aec``, ``barge_in``, ``turn_detection``.

Real audio made offline (:mod:`embagents.bench.echo_room`): the robot's own
Piper voice played through a simulated echo path (a delay and a synthetic
room impulse response), mixed with user speech from the same voice; the
ground truth (when the user starts and stops) comes from how the clip was built.

- ``aec``: 20 robot answers played through 20 rooms (delays 20-48 ms, RT60
  0.2-0.4 s, echo at -26 dBFS RMS, a -65 dBFS noise floor) into
  :class:`~embagents.components.echo_cancel.EchoCanceller` (WebRTC AEC3 from
  the livekit wheel) with the speaker's stamped reference, in one continuous
  stream. ``erle_db``: echo power in / out over all 20 (noise-free pass);
  ``vad_echo_triggers``: segments in which Silero VAD (the SpeechToText
  settings) finds speech in the cancelled echo, with ``vad_echo_triggers_without_aec``
  on the same audio uncancelled. Bars: ``erle_db`` >= 20, ``vad_echo_triggers`` == 0.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from embagents.bench.registry import BenchOptions, case

__all__: list[str] = []

RATE = 16000
CHUNK = 1600  # 100 ms


def _echo_stream(n: int, noise_db: float | None) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """``(played, mic, echo)`` per segment: the robot's line, what the mic hears, the echo alone (float)."""
    from embagents.bench.echo_room import (
        ROBOT_LINES,
        echo_of,
        robot_says,
        room_impulse_response,
        to_int16,
    )

    rng = np.random.default_rng(7)
    played, mic, echo = [], [], []
    for i in range(n):
        line = robot_says(ROBOT_LINES[i % len(ROBOT_LINES)])
        line = np.concatenate([line, np.zeros(RATE, np.int16)])  # a second of silence after each answer
        h = room_impulse_response(RATE, delay_ms=20 + 1.5 * i, rt60_s=0.2 + 0.01 * i, seed=i)
        e = echo_of(line, h, level_db=-26.0)
        m = e + (rng.standard_normal(len(e)) * 10 ** (noise_db / 20) if noise_db is not None else 0.0)
        played.append(line)
        mic.append(to_int16(m))
        echo.append(e)
    return played, mic, echo


def _cancel(played: list[np.ndarray], mic: list[np.ndarray],
            took: list[float] | None = None) -> list[np.ndarray]:
    """Each segment's microphone audio through one EchoCanceller, as a Microphone runs it (100 ms chunks).

    ``took`` gets the seconds each 100 ms chunk took to cancel.
    """
    from embagents.components.echo_cancel import EchoCanceller

    aec = EchoCanceller(RATE)
    t0, at, out = 1000.0, 0, []
    for ref, m in zip(played, mic, strict=True):
        aec.reference(ref, RATE, stamp=t0 + at / RATE)  # the speaker announces what it plays ahead of time
        seg = []
        for i in range(0, len(m), CHUNK):
            start = time.perf_counter()
            seg.append(aec.process(m[i:i + CHUNK], stamp=t0 + (at + i + CHUNK) / RATE))
            if took is not None:
                took.append(time.perf_counter() - start)
        out.append(np.concatenate(seg))
        at += len(m)
    return out


def _vad_triggers(segments: list[np.ndarray]) -> int:
    from embagents.models.backends.sherpa_vad import SpeechSegmenter
    from embagents.speechfiles import silero_vad_path

    vad = SpeechSegmenter(silero_vad_path(), min_silence_ms=500, min_speech_ms=250)
    triggered = 0
    for seg in segments:
        x = seg.astype(np.float32) / 32768.0
        found = []
        for i in range(0, len(x), CHUNK):
            found += vad.feed(x[i:i + CHUNK])
        found += vad.flush()
        triggered += bool(found)
    return triggered


@case("aec", transport="embagents", kind="speech", needs="sherpa_onnx")
def aec(opts: BenchOptions) -> dict[str, Any]:
    from embagents.components.echo_cancel import erle_db

    n = 5 if opts.quick else 20
    played, mic, _ = _echo_stream(n, noise_db=None)
    took: list[float] = []
    out = _cancel(played, mic, took)
    erle = erle_db(np.concatenate(mic), np.concatenate(out))
    erle_after_first = erle_db(np.concatenate(mic[1:]), np.concatenate(out[1:]))
    played, noisy, _ = _echo_stream(n, noise_db=-65.0)
    cancelled = _cancel(played, noisy)
    with_aec, without = _vad_triggers(cancelled), _vad_triggers(noisy)
    return {
        "p50_us": float(np.percentile(took, 50)) * 1e6, "p99_us": float(np.percentile(took, 99)) * 1e6,
        "msgs_per_s": None, "erle_db": round(erle, 1), "erle_db_after_first": round(erle_after_first, 1),
        "vad_echo_triggers": with_aec, "vad_echo_triggers_without_aec": without, "segments": n,
        "note": f"the robot's Piper voice through {n} simulated rooms (20-48 ms, RT60 0.2-0.4 s, echo -26 dBFS): "
                f"ERLE {erle:.1f} dB ({erle_after_first:.1f} dB after the first answer); Silero VAD fired on "
                f"{with_aec}/{n} echo-only answers with AEC, {without}/{n} without; p50/p99 = cancelling one 100 ms "
                "chunk; bars: erle_db >= 20, "
                "vad_echo_triggers == 0",
    }
