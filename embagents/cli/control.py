"""``embagents status|restart|stop``: requests to a live run's control endpoint (:mod:`supervisor.client`)."""

from __future__ import annotations

import argparse

from supervisor.client import control

__all__ = ["arguments", "run", "run_arguments"]

def run_arguments(parser: argparse.ArgumentParser) -> None:
    """``--run`` and ``--timeout``: which live run, and how long to wait for its answer."""
    parser.add_argument("--run", help="run id, system name or pid (default: the only live run)")
    parser.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the run to answer")


def arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of the control command the parser is for (its ``prog`` ends with the command)."""
    cmd = parser.prog.split()[-1]
    run_arguments(parser)
    if cmd == "status":
        parser.add_argument("--json", action="store_true", help="print the status as JSON")
        parser.add_argument(
            "--wait-ready", nargs="?", type=float, const=60.0, metavar="TIMEOUT",
            help="first wait until the run is ready, every component active (at most TIMEOUT s, default 60; "
                 "a run not started yet is waited for too); exit 1 if it is not",
        )
    if cmd == "restart":
        parser.add_argument("name", help="the actor to restart")


def run(args: argparse.Namespace) -> int:
    """Send ``args.command`` to the run and print its answer."""
    return control(args.command, run=args.run, timeout=args.timeout, as_json=getattr(args, "json", False),
                   name=getattr(args, "name", None), wait_ready_s=getattr(args, "wait_ready", None))
