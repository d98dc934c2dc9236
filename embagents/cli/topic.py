"""``embagents topic list|echo|hz|pub``: look at and poke the topics of a live run.

- ``list``: name, type, publishers, subscribers, rate (messages/s).
- ``echo NAME``: each message as ``key: value`` text (``--json``: one JSON
  object a line); arrays as shape and dtype unless ``--full-arrays``.
- ``hz NAME``: every second, the average rate and the min / max / std dev of
  the period over the last ``--window`` messages (as ``ros2 topic hz``).
- ``pub NAME TYPE DATA``: DATA is YAML or JSON (``'{data: hi}'``), or for a
  type whose ``data`` is text (String) the text itself (``'What is it?'``),
  published once or at ``--rate`` Hz through the root.

``echo`` and ``hz`` subscribe keep-latest: a terminal that stops reading
drops messages and never slows a publisher.

Example::

    $ embagents topic echo text_out -n 1
    data: Rome
    ---
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections import deque
from typing import Any

from actors import UnsafeFolder
from actors.codec import message_class
from embagents.cli.control import run_arguments
from embagents.live import connect, find_topic
from embagents.tools.attach import Attached, interrupted_by_sigterm, run_topics
from embagents.tools.plain import field_types, format_text, to_plain
from embagents.tools.publish import publish
from supervisor.client import ControlError

__all__ = ["arguments", "publish_arguments", "publish_run", "run"]


def arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="topic_cmd", metavar="list|echo|hz|pub", required=True)
    parsers = {
        "list": sub.add_parser("list", help="the run's topics: type, publishers, subscribers, rate"),
        "echo": sub.add_parser("echo", help="print the messages of a topic"),
        "hz": sub.add_parser("hz", help="the rate of a topic"),
        "pub": sub.add_parser("pub", help="publish a message given as YAML/JSON"),
    }
    for p in parsers.values():
        run_arguments(p)
    parsers["list"].add_argument("--json", action="store_true", help="print the rows as JSON")
    for name in ("echo", "hz", "pub"):
        parsers[name].add_argument("name", help="the topic, e.g. camera/image")
    echo = parsers["echo"]
    echo.add_argument("--json", action="store_true", help="one JSON object per line")
    echo.add_argument("--full-arrays", action="store_true", help="print arrays in full, not as shape and dtype")
    echo.add_argument("-n", "--count", type=int, help="exit after this many messages")
    hz = parsers["hz"]
    hz.add_argument("--window", type=int, default=100, help="messages the statistics cover (default 100)")
    for p in (echo, hz):
        p.add_argument("--duration", type=float, help="exit after this many seconds")
    pub = parsers["pub"]
    pub.add_argument("type", help="the message type, e.g. String (must be the topic's)")
    pub.add_argument("data", nargs="?", default="{}",
                     help="fields as YAML or JSON, e.g. '{data: hello}'; for String, the text alone: 'hello?'")
    pub.add_argument("-r", "--rate", type=float, help="publish repeatedly at this rate in Hz (Ctrl-C stops)")
    pub.add_argument("-t", "--times", type=int, help="with --rate: stop after this many messages")


def _list(args: argparse.Namespace) -> int:
    found, rows = run_topics(args.run, args.timeout)
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    table = [["TOPIC", "TYPE", "KEEP", "PUBLISHERS", "SUBS", "RATE HZ"]] + [
        [r["name"], r["type"], r["keep"], ",".join(r["publishers"]) or "-", str(r["subscribers"]),
         "-" if r["rate"] is None else f"{r['rate']:.1f}"] for r in rows]
    widths = [max(len(row[i]) for row in table) for i in range(len(table[0]))]
    print(f"{found['system']}  run {found['run_id']}")
    for row in table:
        print("  ".join(c.rjust(w) if i >= 4 else c.ljust(w) for i, (c, w) in enumerate(zip(row, widths, strict=True))).rstrip())
    return 0


def _echo(args: argparse.Namespace) -> int:
    with connect(args.run, timeout=args.timeout) as live, interrupted_by_sigterm():
        topic = live.topic(args.name)["name"]
        messages = live.echo(topic, count=args.count, timeout=args.duration)
        try:
            for msg in messages:
                plain = to_plain(msg, full_arrays=args.full_arrays)
                print(json.dumps(plain) if args.json else format_text(plain) + "\n---", flush=True)
        except KeyboardInterrupt:
            pass
        finally:
            messages.close()
        if messages.dropped:
            print(f"echo: {messages.dropped} messages on {topic} dropped (this terminal was slower than the topic)",
                  file=sys.stderr)
    return 0


def _period_stats(times: deque[float]) -> str:
    periods = [b - a for a, b in zip(times, list(times)[1:], strict=False)]
    mean = sum(periods) / len(periods)
    std = math.sqrt(sum((p - mean) ** 2 for p in periods) / len(periods))
    return (f"average rate: {1 / mean if mean > 0 else float('inf'):.3f}\n"
            f"\tmin: {min(periods):.4f}s max: {max(periods):.4f}s std dev: {std:.5f}s window: {len(times)}")


def _hz(args: argparse.Namespace) -> int:
    found, rows = run_topics(args.run, args.timeout)
    topic = find_topic(rows, args.name)["name"]
    times: deque[float] = deque(maxlen=max(args.window, 2))

    with Attached(found) as seat:
        def report() -> None:
            print(_period_stats(times) if len(times) >= 2 else "no new messages", flush=True)
            seat.loop.call_later(1.0, report)

        seat.subscribe(topic, lambda _msg: times.append(time.monotonic()), queue_size=100)
        seat.loop.call_later(1.0, report)
        seat.run(timeout=args.duration)
    return 0


def _text_type(row: dict[str, Any]) -> bool:
    """Whether the topic's type has a ``data`` field of text (String, StreamingString)."""

    try:
        cls = message_class(row["wire"]) if row.get("wire") else None
    except Exception:  # a wire name this process does not know: take DATA as fields
        return False
    return cls is not None and field_types(cls).get("data") is str


def _fields(data: str, row: dict[str, Any]) -> dict[str, Any]:
    """The fields DATA gives: a YAML/JSON mapping, or for a text type, DATA itself as ``data``."""
    import yaml

    text = _text_type(row)
    if text and not data.lstrip().startswith("{"):
        return {"data": data}  # 'What is the capital of Japan?': no YAML to get wrong
    said = data.strip().removeprefix("{").removesuffix("}").partition(":")[2].strip() or "your text"
    quote = (f"; put the text in double quotes, '{{data: \"{said}\"}}', or give it alone: "
             f"embagents topic pub {row['name']} {row['type']} '{said}'" if text else
             "; e.g. '{data: hello}', with text in double quotes inside: '{data: \"a: b?\"}'")
    try:
        fields = yaml.safe_load(data)
    except yaml.YAMLError as exc:
        problem = str(exc).splitlines()[0]
        raise ValueError(f"DATA {data!r} is neither YAML nor JSON ({problem}){quote}") from None
    fields = {} if fields is None else fields
    if not isinstance(fields, dict):
        raise ValueError(f"DATA must be a mapping of fields such as '{{data: hello}}', got {fields!r}{quote}")
    return fields


def _pub(args: argparse.Namespace) -> int:
    with connect(args.run, timeout=args.timeout) as live:
        row = find_topic(live.topics(), args.name)
        if args.type not in (row["type"], row["wire"]):
            raise ControlError(f"topic {row['name']!r} carries {row['type']}, not {args.type}: "
                               f"`embagents topic pub {row['name']} {row['type']} ...`")
        fields = _fields(args.data, row)
        if args.rate is None:
            live.publish(row["name"], **fields)
            print(f"published {row['type']} on {row['name']}")
            return 0
        if args.rate <= 0:
            raise ValueError(f"--rate must be above 0 Hz, got {args.rate}")
        sent, period, start = 0, 1.0 / args.rate, time.monotonic()
        try:
            while args.times is None or sent < args.times:
                live.publish(row["name"], **fields)
                sent += 1
                time.sleep(max(0.0, start + sent * period - time.monotonic()))  # keeps the rate, not the gaps
        except KeyboardInterrupt:
            pass
    print(f"published {sent} {row['type']} on {row['name']} at {args.rate:g} Hz")
    return 0


def publish_arguments(parser: argparse.ArgumentParser) -> None:
    """``embagents publish TOPIC [TEXT] [--fields JSON]``: ``topic pub`` without the type, for text topics."""
    run_arguments(parser)
    parser.add_argument("topic", help="a topic of the running system, e.g. text_in")
    parser.add_argument("text", nargs="?", help="the message's `data` field (String, StreamingString)")
    parser.add_argument("--fields", metavar="JSON", help='other fields as a JSON object, e.g. \'{"data": "hi"}\'')


def publish_run(args: argparse.Namespace) -> int:
    """Run ``embagents publish``: the same request as ``topic pub`` (:meth:`embagents.live.LiveRun.publish`)."""
    try:
        reply = publish(args.topic, args.text, args.fields, run=args.run, timeout=args.timeout)
    except (ControlError, UnsafeFolder, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"published {reply['type']} on {reply['topic']} (run {reply['run_id']}, system {reply['system']})")
    return 0


def run(args: argparse.Namespace) -> int:
    """Run ``embagents topic ...``; 1 with a one-line error for bad input."""
    commands = {"list": _list, "echo": _echo, "hz": _hz, "pub": _pub}
    try:
        return commands[args.topic_cmd](args)
    except (ControlError, UnsafeFolder, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # `embagents topic echo x | head`
        return 0
