"""Counting the ``chaos`` case's records: what was lost, what was handled twice.

The records are the files the workers of :mod:`embagents.bench.chaos_workers`
write, one per process (incarnation). What counts:

- **tells** (at-least-once): every number up to the source's final
  acknowledged watermark W (the highest number whose tell the sink
  acknowledged, in any source incarnation) must be in some sink
  incarnation's file. ``lost_tell`` = numbers in ``0..W`` never handled.
  ``duplicated_tell`` = extra handlings of a number (a sink SIGKILLed after
  handling a tell, before acknowledging it, handles it again; a source
  restarted from an older snapshot sends again what was not acknowledged);
  ``duplicated_tell_same_incarnation`` counts only the same tell (number and
  source incarnation) handled twice by one sink incarnation (never expected).
- **keep-all topic** (a stream: what is published while the subscriber is
  down is not delivered): for each pair (sink incarnation, source
  incarnation) the numbers handled must be every number from the first to
  the last of them. A gap is a message published while both sides lived and
  never handled: ``dropped_topic`` if the sink's subscription counted it as
  dropped (its ``D total`` lines: a publisher drops, counted, for a
  subscriber that has not read for its stall bound, e.g. one SIGSTOPped
  until its heartbeat deadline; see :mod:`actors.topics`), ``lost_topic``
  if nothing counted it. Gaps are matched to the count in the order they
  open, so an uncounted one is never hidden by a count (when both occur in
  one incarnation, which numbers are called lost may be off; how many is not).

Example::

    >>> tally_numbers({"sink-1.log": "T 0 9\\nT 1 9\\nS 0 9\\nS 2 9\\n", "sink-2.log": "T 1 9\\nT 3 9\\n"}, acked=3)["lost_tell"]
    [2]
    >>> tally_numbers({"sink-1.log": "S 0 9\\nS 2 9\\n"}, acked=-1)["lost_topic"]
    [[1, 9, 1]]
    >>> t = tally_numbers({"sink-1.log": "S 0 9\\nD 2\\nS 3 9\\nS 6 9\\n"}, acked=-1)
    >>> t["dropped_topic"], t["lost_topic"]
    (2, [[4, 9, 1], [5, 9, 1]])
"""

from __future__ import annotations

import os
from collections import Counter, defaultdict
from typing import Any

__all__ = ["read_records", "tally_frames", "tally_numbers", "watermark"]


def read_records(workdir: str, stem: str) -> dict[str, str]:
    """The text of every ``<stem>-<pid>.log`` in ``workdir``, by file name."""
    out = {}
    for name in sorted(os.listdir(workdir)):
        if name.startswith(f"{stem}-") and name.endswith(".log") and name[len(stem) + 1:-4].isdigit():
            with open(os.path.join(workdir, name)) as f:
                out[name] = f.read()
    return out


def _lines(text: str) -> list[list[str]]:
    # A SIGKILL can cut the last line of a file short: keep whole lines only.
    return [ln.split() for ln in text.splitlines(keepends=True) if ln.endswith("\n")]


def watermark(source_files: dict[str, str]) -> tuple[int, int]:
    """``(acked, sent)``: the highest acknowledged and the highest sent number over all source incarnations.

    >>> watermark({"source-1.log": "A 9 19\\n", "source-2.log": "A 29 39\\nA 3"})
    (29, 39)
    """
    acked = sent = -1
    for text in source_files.values():
        for f in _lines(text):
            if f[0] == "A":
                acked, sent = max(acked, int(f[1])), max(sent, int(f[2]))
    return acked, sent


def tally_numbers(sink_files: dict[str, str], acked: int) -> dict[str, Any]:
    """Lost, dropped (counted) and duplicated numbers of both channels (see the module docs).

    ``lost_topic`` lists ``[number, source pid, sink pid]``; ``dropped_topic`` is a count; files are named
    ``sink-<pid>.log``.
    """
    tells: Counter[int] = Counter()
    same_inc_dups = 0
    lost_topic: list[list[int]] = []
    dup_topic = 0
    dropped_topic = 0
    for fname, text in sink_files.items():
        sink_pid = int(fname.rsplit("-", 1)[1].removesuffix(".log"))
        mine: Counter[tuple[int, int]] = Counter()  # (number, source pid)
        seen: dict[int, set[int]] = defaultdict(set)  # source pid -> topic numbers handled
        top: dict[int, int] = {}  # source pid -> the highest of them
        gaps: list[tuple[int, int, bool]] = []  # (number, source pid, counted as dropped)
        counted = used = 0  # the subscription's drop count so far; how much of it gaps have taken
        for f in _lines(text):
            if f[0] == "D":
                counted = int(f[1])
                continue
            n, src = int(f[1]), int(f[2])
            if f[0] == "T":
                mine[n, src] += 1
            elif f[0] == "S":
                if n in seen[src]:
                    dup_topic += 1
                    continue
                seen[src].add(n)
                hi = top.setdefault(src, n)
                for m in range(hi + 1, n):  # a gap opens
                    gaps.append((m, src, used < counted))
                    used += used < counted
                top[src] = max(hi, n)
        same_inc_dups += sum(c - 1 for c in mine.values())
        tells.update(n for (n, _), c in mine.items() for _ in range(c))
        for n, src, ok in gaps:
            if n in seen[src]:  # it came later after all
                continue
            if ok:
                dropped_topic += 1
            else:
                lost_topic.append([n, src, sink_pid])
    return {
        "lost_tell": [n for n in range(acked + 1) if n not in tells],
        "duplicated_tell": sum(c - 1 for c in tells.values()),
        "duplicated_tell_same_incarnation": same_inc_dups,
        "handled_tell": len(tells),
        "lost_topic": lost_topic,
        "dropped_topic": dropped_topic,
        "duplicated_topic": dup_topic,
        "sink_incarnations": len(sink_files),
    }


def tally_frames(sink_files: dict[str, str], source_files: dict[str, str]) -> dict[str, int]:
    """Frames published and received, and received frames whose pixels were not the ones sent.

    >>> tally_frames({"frames-sink-5.log": "R 0 ok\\nR 2 torn\\n"}, {"frames-source-4.log": "P 0\\nP 1\\nP 2\\n"})
    {'frames_published': 3, 'frames_received': 2, 'frames_torn': 1}
    """
    received = [f for text in sink_files.values() for f in _lines(text) if f[0] == "R"]
    published = sum(1 for text in source_files.values() for f in _lines(text) if f[0] == "P")
    return {
        "frames_published": published,
        "frames_received": len(received),
        "frames_torn": sum(1 for f in received if f[2] != "ok"),
    }
