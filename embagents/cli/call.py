"""``embagents call COMPONENT METHOD [ARGS...]``: run a component's action in the running system."""

from __future__ import annotations

import argparse
import json
import sys

from actors import UnsafeFolder
from embagents.cli.control import run_arguments
from embagents.tools.call import call, parse_args
from supervisor.client import ControlError

__all__ = ["arguments", "run"]


def arguments(parser: argparse.ArgumentParser) -> None:
    run_arguments(parser, 120.0, waits_for="the method to return")
    parser.add_argument("component", help="a component of the running system, e.g. vlm")
    parser.add_argument("method", help="its action, e.g. describe")
    parser.add_argument("args", nargs="*", help="arguments: JSON when they parse (3, true, [1, 2]), else strings")
    parser.add_argument("--kwargs", metavar="JSON", help='keyword arguments as a JSON object, e.g. \'{"query": "hi"}\'')
    parser.add_argument("-v", "--verbose", action="store_true", help="with an error the action raised: its traceback")


def run(args: argparse.Namespace) -> int:
    try:
        kwargs = json.loads(args.kwargs) if args.kwargs else {}
        if not isinstance(kwargs, dict):
            raise ValueError(f"--kwargs must be a JSON object, got {args.kwargs!r}")
        reply = call(args.component, args.method, parse_args(args.args), kwargs, run=args.run, timeout=args.timeout)
    except (ControlError, UnsafeFolder, ValueError) as exc:
        remote = (getattr(exc, "reply", None) or {}).get("traceback")
        if remote and args.verbose:
            print(f"remote traceback ({args.component}'s process):\n{remote.rstrip()}", file=sys.stderr)
        print(f"error: {exc}" + (" (-v: its traceback)" if remote and not args.verbose else ""), file=sys.stderr)
        return 1
    print(f"{args.component}.{args.method} -> {reply['result']!r}")
    return 0
