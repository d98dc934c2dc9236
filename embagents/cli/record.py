"""``embagents record [TOPICS...] -o FILE.mcap``: record a live run's topics to MCAP.

The recorder is an actor supervised by the run's root
(:class:`~embagents.tools.recorder.RecorderActor`): it goes on when any other
actor crashes, and is restarted (into the next file) if it crashes itself.
This command starts it, waits for Ctrl-C (or ``--duration``), stops it and
prints what each file holds. ``--detach`` leaves it recording;
``embagents record --stop FILE.mcap`` stops it later.

Example::

    $ embagents record -o /tmp/run.mcap --max-size 500 --duration 10
    recording 4 topics to /tmp/run.mcap (Ctrl-C stops)
    /tmp/run.mcap: 312 messages on 4 topics, 2.1 MB
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from typing import Any

from actors import UnsafeFolder
from embagents.cli.control import run_arguments
from embagents.tools.recorder import refusal
from supervisor.client import ControlError, pick_run, request

__all__ = ["arguments", "run", "summary"]


def arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("topics", nargs="*", metavar="TOPIC", help="topics to record (default: all)")
    parser.add_argument("-o", "--output", metavar="FILE.mcap", help="the file to write (required unless --stop)")
    parser.add_argument("--max-size", type=float, metavar="MB", help="start a new file past this size")
    parser.add_argument("--max-duration", type=float, metavar="S", help="start a new file after this many seconds")
    parser.add_argument("--max-files", type=int, metavar="N", help="keep only the newest N files")
    parser.add_argument("--compression", choices=("none", "lz4", "zstd"), default="lz4", help="chunk compression")
    parser.add_argument("--chunk-size", type=float, default=256, metavar="KB",
                        help="chunk size: a killed recorder loses at most its open chunk (default 256 KB)")
    parser.add_argument("--overwrite", action="store_true", help="replace FILE.mcap (and its rotations) if present")
    parser.add_argument("--duration", type=float, metavar="S", help="stop after this many seconds")
    parser.add_argument("--detach", action="store_true", help="start the recorder and return")
    parser.add_argument("--stop", metavar="FILE.mcap", help="stop the recorder writing FILE.mcap")
    run_arguments(parser, 10.0)


def summary(path: str) -> str:
    """``path: N messages on M topics, X MB`` (or what is wrong with it)."""
    from mcap.reader import make_reader

    size = os.path.getsize(path) / 1e6
    try:
        with open(path, "rb") as f:
            stats = make_reader(f).get_summary()
        if stats is None or stats.statistics is None:
            raise ValueError("no summary")
        topics = len({c.topic for c in stats.channels.values()})
        return f"{path}: {stats.statistics.message_count} messages on {topics} topics, {size:.1f} MB"
    except Exception as exc:  # a killed recorder's file: no summary, still playable
        return f"{path}: {size:.1f} MB, not finished ({type(exc).__name__}); `embagents play` reads what is there"


def _stop(run_dir: str, path: str, timeout: float) -> list[str]:
    return list(request(run_dir, {"cmd": "record_stop", "path": path}, timeout)["files"])


def _wait(duration: float | None) -> None:
    done = threading.Event()
    old = signal.signal(signal.SIGTERM, lambda *_: done.set())
    try:
        done.wait(duration)
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, old)


def run(args: argparse.Namespace) -> int:
    """Run ``embagents record``; 1 with a one-line error when the run refuses."""
    try:
        found = pick_run(args.run)
        if args.stop:
            for f in _stop(found["run_dir"], os.path.abspath(args.stop), args.timeout):
                print(summary(f))
            return 0
        if not args.output:
            raise ValueError("say where to record: -o FILE.mcap")
        path = os.path.abspath(args.output)
        if os.path.islink(path):  # the recorder refuses it too (O_NOFOLLOW); said here, before it starts

            raise ValueError(str(refusal(path)))
        req: dict[str, Any] = {
            "cmd": "record_start", "path": path, "topics": [t.removeprefix("/") for t in args.topics],
            "max_bytes": int(args.max_size * 1e6) if args.max_size else None, "max_seconds": args.max_duration,
            "max_files": args.max_files, "compression": args.compression,
            "chunk_bytes": max(1, int(args.chunk_size * 1024)), "overwrite": args.overwrite,
        }
        reply = request(found["run_dir"], req, args.timeout)
        print(f"recording {len(reply['topics'])} topics to {path} "
              + ("(stop with `embagents record --stop " + path + "`)" if args.detach else "(Ctrl-C stops)"), flush=True)
        if args.detach:
            return 0
        _wait(args.duration)
        for f in _stop(found["run_dir"], path, args.timeout):
            print(summary(f))
    except (ControlError, UnsafeFolder, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0
