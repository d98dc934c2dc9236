"""``embagents bench``: measure embagents side by side with the alternatives (:mod:`embagents.bench`).

The options are defined here once: ``python -m embagents.bench`` takes them too; the run is
:func:`embagents.bench.run` (imported only then: the bench package is heavy).
"""

from __future__ import annotations

import argparse

__all__ = ["arguments"]


def arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", metavar="FILE", help="also write the results as JSON to FILE")
    parser.add_argument("--quick", action="store_true", help="a smoke test: few iterations, 2 s idle window, no PASS/FAIL verdicts")
    parser.add_argument(
        "--only", nargs="+", metavar="NAME",
        help="run only cases matching NAME (a case name, glob, substring, transport or kind)",
    )
    parser.add_argument(
        "--minutes", type=float, metavar="N",
        help="how long the chaos case injects faults (default 1; 0.1 with --quick)",
    )
    parser.add_argument("--list", action="store_true", help="list the cases in run order and exit")
    parser.add_argument("--strict", action="store_true", help="exit with status 2 if a bar fails")

