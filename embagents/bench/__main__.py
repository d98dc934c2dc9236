"""``python -m embagents.bench [--json FILE] [--quick] [--only NAME...]``.

Example::

    python -m embagents.bench --quick --json /tmp/bench.json
"""

from __future__ import annotations

import argparse
import sys

from embagents.bench import run
from embagents.cli.bench import arguments


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv`` and run the benchmark; returns the exit status."""
    parser = argparse.ArgumentParser(
        prog="python -m embagents.bench",
        description="Measure embagents' actors side by side with raw pyzmq, multiprocessing queues and rclpy.",
    )
    arguments(parser)  # the options of `embagents bench`, defined once
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
