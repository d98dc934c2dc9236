"""``embagents status|restart|stop``: requests to a live run's control endpoint (:mod:`supervisor.client`)."""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from typing import Any

from actors import UnsafeFolder
from embagents.tools.root import voice_lines
from supervisor.client import ControlError, control, pick_run, request, wait_ready

__all__ = ["restart_arguments", "run", "run_arguments", "status_arguments"]


def run_arguments(parser: argparse.ArgumentParser, timeout: float | None = 5.0,
                  waits_for: str = "the run to answer") -> None:
    """``--run`` (which live run) and ``--timeout`` (how long to wait for ``waits_for``; none when ``timeout`` is None)."""
    parser.add_argument("--run", help="run id, system name or pid (default: the only live run)")
    if timeout is not None:
        parser.add_argument("--timeout", type=float, default=timeout, help=f"seconds to wait for {waits_for}")


def status_arguments(parser: argparse.ArgumentParser) -> None:
    run_arguments(parser)
    parser.add_argument("--json", action="store_true", help="print the status as JSON")
    parser.add_argument(
        "--wait-ready", nargs="?", type=float, const=60.0, metavar="TIMEOUT",
        help="first wait until the run is ready, every component active (at most TIMEOUT s, default 60; "
             "a run not started yet is waited for too); exit 1 if it is not",
    )


def restart_arguments(parser: argparse.ArgumentParser) -> None:
    run_arguments(parser)
    parser.add_argument("name", help="the actor to restart")


def run(args: argparse.Namespace) -> int:
    """Send ``args.command`` to the run and print its answer."""
    if args.command == "status":
        return _status(args)
    return control(args.command, run=args.run, timeout=args.timeout, as_json=getattr(args, "json", False),
                   name=getattr(args, "name", None), wait_ready_s=getattr(args, "wait_ready", None))


def _status(args: argparse.Namespace) -> int:
    """`embagents status`: the supervisor's table, then the voice stages of the run's VoiceStage topics."""
    if args.json:  # one JSON object: the status with its "voice" key
        try:
            picked = (wait_ready(args.run, args.wait_ready) if args.wait_ready is not None else pick_run(args.run))
            reply = request(picked["run_dir"], {"cmd": "status"}, args.timeout)
            reply["voice"] = _voice_stages(picked["run_dir"], args.timeout)
        except (ControlError, UnsafeFolder) as exc:
            print(json.dumps({"ok": False, "error": str(exc)}))
            print(f"error: {exc}", file=sys.stderr)
            return 1
        print(json.dumps(reply, indent=2))
        return 0
    rc = control("status", run=args.run, timeout=args.timeout, wait_ready_s=args.wait_ready)
    if rc == 0:
        with contextlib.suppress(ControlError):
            for line in voice_lines(_voice_stages(pick_run(args.run)["run_dir"], args.timeout) or {}):
                print(line)
    return rc


def _voice_stages(run_dir: str, timeout: float) -> dict[str, Any] | None:
    """The run's ``voice_stages`` answer; None from a run that does not serve it."""
    try:
        reply = request(run_dir, {"cmd": "voice_stages"}, timeout)
        return {k: reply.get(k) for k in ("topics", "turns", "latest", "p50")}
    except ControlError as exc:
        if "unknown command" in str(exc):
            return None
        raise
