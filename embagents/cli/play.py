"""``embagents play FILE.mcap``: publish a recording into a live run.

Messages go out on their recorded topics at the recorded timing
(``--rate 2`` twice as fast, ``--fast`` as fast as they can, ``--step``
one per Enter). A file that is cut short (a killed recorder, a copy that
broke off) or corrupt plays up to its last readable message, and the
command says at which byte and after which message it stopped (exit 1).
Only topics no component of the run publishes are played by default (a
recording of a chat run holds its questions and its answers: playing both
into a live run would double and garble the answers); the command names the
topics it skipped, and ``--all`` plays them too. Topics starting with ``_``
(supervisor events, health), ``system_stop`` (it would stop the run) and
topics the run does not declare are skipped unless named with ``--topics``.

Example::

    $ embagents play /tmp/run.mcap --rate 2
    skipped text_out (12 messages: published by llm; --all plays it too)
    played 12 messages on 1 topics from /tmp/run.mcap
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Iterator
from datetime import datetime, timezone
from typing import Any, NamedTuple

from actors import UnsafeFolder
from actors.topics import Publisher
from embagents.cli.control import run_arguments
from embagents.tools.attach import Attached, run_topics
from embagents.tools.mcap_codec import decode
from supervisor.client import ControlError

__all__ = ["MCAP_MAGIC", "Stopped", "arguments", "read_messages", "run"]

#: The first bytes of every MCAP file.
MCAP_MAGIC = b"\x89MCAP0\r\n"
#: Publishing anything here stops the run (:data:`embagents.system.SYSTEM_STOP`): played only when named.
SYSTEM_STOP = "system_stop"


def arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("files", nargs="+", metavar="FILE.mcap", help="recordings, played one after another")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--rate", type=float, default=1.0, help="speed factor (default 1: recorded timing)")
    pace.add_argument("--fast", action="store_true", help="as fast as possible")
    pace.add_argument("--step", action="store_true", help="one message per Enter")
    parser.add_argument("--topics", nargs="+", metavar="TOPIC",
                        help="play only these topics (any topic named here is played, even system_stop)")
    parser.add_argument("--all", action="store_true",
                        help="also play topics that components of the run publish (default: skipped, and named)")
    run_arguments(parser)


class Stopped(NamedTuple):
    """Where reading a file stopped early, and why."""

    path: str
    offset: int
    size: int
    reason: str


def read_messages(path: str, stopped: list[Stopped]) -> Iterator[tuple[str, int, Any]]:
    """``(topic, log_time ns, message)`` of ``path`` in file order, up to what is readable.

    A cut or corrupt file appends a :class:`Stopped` to ``stopped`` and ends the iteration.
    """
    import os

    from mcap.reader import NonSeekingReader


    size = os.path.getsize(path)
    with open(path, "rb") as f:
        head = f.read(len(MCAP_MAGIC))
        if not head or not MCAP_MAGIC.startswith(head):  # a file of another kind, not a cut MCAP
            what = f"it starts with {head!r}, an MCAP file with {MCAP_MAGIC!r}" if head else "it is empty"
            stopped.append(Stopped(path, 0, size, f"not an MCAP file ({what}); "
                                   "`embagents record -o FILE.mcap` makes one"))
            return
        f.seek(0)
        reader = NonSeekingReader(f, record_size_limit=1 << 30)
        try:
            for schema, channel, message in reader.iter_messages(log_time_order=False):
                yield channel.topic, message.log_time, decode(schema.name if schema else "", message.data)
        except Exception as exc:  # a cut or damaged file: what came before was played
            reason = f"{type(exc).__name__}: {exc}".rstrip(": ")
            if f.tell() >= size:  # EndOfFile, or a header cut in two
                reason = "the file ends inside a record: cut short, by a killed recorder or an incomplete copy"
            stopped.append(Stopped(path, f.tell(), size, reason))


class _Skips:
    """Which recorded topics are not played, and why (see the module doc); counts what each skip left out."""

    def __init__(self, rows: list[dict[str, Any]], named: list[str], everything: bool) -> None:
        self.known = {r["name"]: r for r in rows}
        self.named, self.everything = set(named), everything
        self.skipped: dict[str, list[Any]] = {}  # topic -> [why, messages]
        self.played: set[str] = set()

    def why(self, topic: str) -> str | None:
        """Why ``topic`` is not played (None: it is)."""
        if self.named:
            return None if topic in self.named else "not named in --topics"
        if topic.startswith("_"):
            return "the runtime's own; name it with --topics to play it"
        if topic == SYSTEM_STOP:
            return "it would stop the run; name it with --topics to play it"
        row = self.known.get(topic)
        if row is None:
            return "not a topic of this run; name it with --topics to play it"
        components = [p for p in row["publishers"] if not p.startswith("(")]
        if components and not self.everything:
            return f"published by {', '.join(components)}; --all plays it too"
        return None

    def __call__(self, topic: str) -> bool:
        """Whether to skip this message of ``topic`` (decided once per topic)."""
        if topic in self.played:
            return False
        entry = self.skipped.get(topic)
        if entry is None:
            why = self.why(topic)
            if why is None:
                self.played.add(topic)
                return False
            entry = self.skipped[topic] = [why, 0]
        entry[1] += 1
        return True

    def report(self) -> list[str]:
        """``skipped TOPIC (N messages: why)`` per topic, but for what ``--topics`` left out on purpose."""
        return [f"skipped {topic} ({n} messages: {why})" for topic, (why, n) in self.skipped.items()
                if why != "not named in --topics"]


def _pace(args: argparse.Namespace, log_time: int, start: list[float]) -> None:
    if args.step:
        input(f"[{log_time / 1e9:.3f}] Enter for the next message ")
        return
    if args.fast:
        return
    if not start:
        start.extend((time.monotonic(), log_time / 1e9))
    due = start[0] + (log_time / 1e9 - start[1]) / args.rate
    time.sleep(max(0.0, due - time.monotonic()))


def run(args: argparse.Namespace) -> int:
    """Play ``args.files`` into the run; 1 if a file stopped early or the input is bad."""

    try:
        if args.rate <= 0:
            raise ValueError(f"--rate must be above 0, got {args.rate}")
        found, rows = run_topics(args.run, args.timeout)
        skip = _Skips(rows, [t.removeprefix("/") for t in args.topics or []], getattr(args, "all", False))
        stopped: list[Stopped] = []
        publishers: dict[str, Publisher] = {}
        start: list[float] = []  # the first message's (wall clock, log time): set by _pace
        count, last = 0, None
        with Attached(found) as seat:
            for path in args.files:
                for topic, log_time, msg in read_messages(path, stopped):
                    if skip(topic):
                        continue
                    if topic not in publishers:
                        if topic not in skip.known:
                            print(f"warning: topic {topic!r} is not declared in this run; published anyway",
                                  file=sys.stderr)
                        publishers[topic] = Publisher(seat.rt, topic)
                    _pace(args, log_time, start)
                    publishers[topic].publish(msg)
                    count, last = count + 1, (topic, log_time)
                if stopped:
                    break
            time.sleep(0.3)  # the last frames leave the sockets before they close
            for p in publishers.values():
                p.close()
        for line in skip.report():
            print(line, file=sys.stderr)
        print(f"played {count} messages on {len(publishers)} topics from {', '.join(args.files)}")
        if stopped:
            s = stopped[0]
            when = datetime.fromtimestamp(last[1] / 1e9, timezone.utc).isoformat(timespec="milliseconds") if last else ""
            after = f"after the message on {last[0]!r} logged at {when}" if last else "before any message"
            print(f"error: {s.path} stopped at byte {s.offset} of {s.size} ({s.reason}); played what was readable, "
                  f"{after}", file=sys.stderr)
            return 1
    except (ControlError, UnsafeFolder, ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 0
    return 0
