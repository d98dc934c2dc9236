"""``embagents check SYSTEM_PY``: validate a system's wiring without starting anything.

Example::

    >>> import argparse
    >>> run(argparse.Namespace(system="/no/such/system.py", offline=False))
    error: [load-error] /no/such/system.py: no such file
    1
"""

from __future__ import annotations

import argparse
import os
import sys

from embagents.check import check_file, errors
from embagents.system import counted

__all__ = ["arguments", "run", "system_argument"]


def system_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("system", metavar="SYSTEM_PY", help="the system.py file declaring `system = System(...)`")


def arguments(parser: argparse.ArgumentParser) -> None:
    system_argument(parser)
    parser.add_argument("--offline", action="store_true",
                        help="embagents.compat recipes: replace model servers by the offline default models")


def run(args: argparse.Namespace) -> int:
    if getattr(args, "offline", False):
        os.environ["EMBAGENTS_OFFLINE"] = "1"  # read by embagents.compat's clients
    system, problems = check_file(args.system)
    for p in problems:
        print(p)
    bad = errors(problems)
    if bad:
        warned = len(problems) - len(bad)
        print(counted(len(bad), "error") + (f", {counted(warned, 'warning')}" if warned else ""), file=sys.stderr)
        return 1
    assert system is not None  # no errors means it loaded
    summary = f"OK: {counted(len(system.components), 'component')}, {counted(len(system.topics), 'topic')}"
    if system.managers:
        summary += f", {counted(len(system.managers), 'manager')}"
    print(summary + (f" ({counted(len(problems), 'warning')})" if problems else ""))
    return 0


