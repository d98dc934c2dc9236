"""Draw docs/speech_vad.png: the speech clip, the utterances Silero VAD cut, what Whisper heard in each.

    python docs/speech_vad.py        (needs matplotlib, and embagents[speech])
"""

from __future__ import annotations

import os
import wave

import numpy as np


def main() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from embagents.components.vad import SpeechSegmenter
    from embagents.models.backends.sherpa_stt import SherpaRecognizer
    from embagents.models.files.speech import silero_vad_path, speech_clip_path, whisper_tiny_en_dir

    with wave.open(speech_clip_path()) as w:
        samples = np.frombuffer(w.readframes(w.getnframes()), np.int16).astype(np.float32) / 32768
    vad = SpeechSegmenter(silero_vad_path(), min_silence_ms=300)
    stt = SherpaRecognizer(whisper_tiny_en_dir())
    spans = []
    for i in range(0, len(samples), 1600):
        spans += list(zip(vad.feed(samples[i:i + 1600]), vad.last_starts, strict=True))
    spans += list(zip(vad.flush(), vad.last_starts, strict=True))
    fig, ax = plt.subplots(figsize=(11, 3.2), dpi=100)
    t = np.arange(len(samples)) / 16000
    ax.plot(t, samples, color="#555", linewidth=0.4)
    for n, (u, start) in enumerate(spans):
        ax.axvspan(start / 16000, (start + len(u)) / 16000, color="#4c9be8", alpha=0.25)
        ax.text((start + len(u) / 2) / 16000, 0.82 if n % 2 else 0.95, stt.transcribe(u), ha="center", va="top",
                fontsize=9, transform=ax.get_xaxis_transform())
    ax.set_xlabel("seconds")
    ax.set_yticks([])
    ax.set_xlim(0, t[-1])
    ax.set_title("beckett.wav: utterances cut by Silero VAD (blue), each transcribed by Whisper tiny.en", fontsize=10)
    fig.tight_layout()
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "speech_vad.png")
    fig.savefig(out)
    print(out)


if __name__ == "__main__":
    main()
