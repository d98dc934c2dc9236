"""Latency per stage of a voice turn: what each voice component publishes, and the turns made of it.

Wire one :class:`~embagents.msgs.VoiceStage` topic as an output of the voice
components and each says when a turn reached its stage (wall time):

==========================  ==================  =====================================================
stage                       published by        when
==========================  ==================  =====================================================
``end_of_speech``           SpeechToText        the user stopped speaking (the audio's pause began)
``end_of_turn``             SpeechToText        the turn was decided finished (turn model or silence)
``transcript``              SpeechToText        the final transcript was passed on
``llm_first_token``         LLM                 the first token of the answer was published
``tts_first_audio``         TextToSpeech        the answer's first audio was published
``speaker_start``           Speaker             that audio was given to the sound device
==========================  ==================  =====================================================

:class:`VoiceTurns` groups them into turns (a turn begins at its
``end_of_speech``) and names the delays as LiveKit's and Pipecat's metrics
do, in ms: ``eou_delay`` (end of speech -> end of turn), ``transcription_delay``
(-> transcript), ``ttft`` (-> first token), ``ttfb`` (-> first audio),
``playout_delay`` (-> speaker start) and ``total`` (end of speech -> speaker
start, or first audio without a speaker). The root of ``embagents supervise``
keeps one for every such topic: ``embagents status`` shows the latest turn and
the p50 of each stage.

Example::

    >>> turns = VoiceTurns()
    >>> for stage, t in (("end_of_speech", 10.0), ("end_of_turn", 10.2), ("transcript", 10.3),
    ...                  ("llm_first_token", 10.45), ("tts_first_audio", 10.6)):
    ...     turns.feed(VoiceStage(stage=stage, stamp=t))
    >>> turns.latest()
    {'eou_delay': 200.0, 'transcription_delay': 100.0, 'ttft': 150.0, 'ttfb': 150.0, 'playout_delay': None, 'total': 600.0}
"""

from __future__ import annotations

import collections
import statistics
import time
from typing import Any

from embagents.msgs import VoiceStage

__all__ = ["DELAYS", "STAGES", "VoiceTurns", "publish_stage"]

#: The stages in the order a turn reaches them.
STAGES = ("end_of_speech", "end_of_turn", "transcript", "llm_first_token", "tts_first_audio", "speaker_start")
#: Each delay: (name, from stage, to stage).
DELAYS = (("eou_delay", "end_of_speech", "end_of_turn"), ("transcription_delay", "end_of_turn", "transcript"),
          ("ttft", "transcript", "llm_first_token"), ("ttfb", "llm_first_token", "tts_first_audio"),
          ("playout_delay", "tts_first_audio", "speaker_start"))


def publish_stage(component: Any, stage: str, stamp: float | None = None) -> None:
    """Publish that ``component`` reached ``stage`` (at ``stamp``, default now) on its VoiceStage outputs."""
    for t in component.outputs:
        if t.msg_type is VoiceStage:
            component.publish(t, VoiceStage(stage=stage, stamp=time.time() if stamp is None else stamp,
                                            source=str(component.name)))


class VoiceTurns:
    """The last ``keep`` turns, from VoiceStage messages in the order they come (see the module docstring)."""

    def __init__(self, keep: int = 100) -> None:
        self.turns: collections.deque[dict[str, float]] = collections.deque(maxlen=keep)

    def feed(self, msg: VoiceStage) -> None:
        if msg.stage == "end_of_speech":
            self.turns.append({"end_of_speech": msg.stamp})
            return
        if msg.stage not in STAGES or not self.turns:
            return  # a stage before any turn began (an answer to a typed question): no voice turn
        turn = self.turns[-1]
        if msg.stage not in turn and msg.stamp >= turn["end_of_speech"]:
            turn[msg.stage] = msg.stamp  # the first of its kind in the turn (an answer's first token, not later ones)

    @staticmethod
    def delays(turn: dict[str, float]) -> dict[str, float | None]:
        """The delays of one turn in ms (None: a stage not reached, or not wired)."""
        def ms(a: str, b: str) -> float | None:
            return round((turn[b] - turn[a]) * 1000, 1) if a in turn and b in turn else None

        out = {name: ms(a, b) for name, a, b in DELAYS}
        end = "speaker_start" if "speaker_start" in turn else "tts_first_audio"
        out["total"] = ms("end_of_speech", end)
        return out

    def latest(self) -> dict[str, float | None]:
        """The delays of the latest turn (empty before the first)."""
        return self.delays(self.turns[-1]) if self.turns else {}

    def p50(self) -> dict[str, float | None]:
        """Each delay's median over the turns that reached both its stages."""
        every = [self.delays(t) for t in self.turns]
        out: dict[str, float | None] = {}
        for n in [name for name, _, _ in DELAYS] + ["total"]:
            values = [v for d in every if (v := d[n]) is not None]
            out[n] = round(statistics.median(values), 1) if values else None
        return out

    def summary(self) -> dict[str, Any]:
        """``{"turns", "latest", "p50"}`` (what ``embagents status`` shows)."""
        return {"turns": len(self.turns), "latest": self.latest(), "p50": self.p50()}
