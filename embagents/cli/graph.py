"""``embagents graph SYSTEM_PY -o FILE``: draw a system as SVG or PNG (broken systems too: it helps fix them)."""

from __future__ import annotations

import argparse
import sys

from embagents.cli.check import system_argument
from embagents.system import SystemFileError, load_system
from embagents.tools.graph import render_graph

__all__ = ["arguments", "run"]


def arguments(parser: argparse.ArgumentParser) -> None:
    system_argument(parser)
    parser.add_argument("-o", "--output", required=True, metavar="FILE", help="where to draw: .svg or .png")


def run(args: argparse.Namespace) -> int:
    try:
        system = load_system(args.system, lenient=True)  # draw broken systems too: it helps fix them
        render_graph(system, args.output)
    except (SystemFileError, ValueError, OSError, RuntimeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {args.output}")
    return 0
