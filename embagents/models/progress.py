"""One progress bar for long steps (model conversions, preparations): a line on stderr.

A terminal sees the bar move in place; a log file (stderr not a tty) gets the
last line only, so a CI log is not filled with carriage returns.

Example::

    >>> import io
    >>> out = io.StringIO()
    >>> show = progress_bar("preparing voice", stream=out)
    >>> for n in range(4):
    ...     show(n, 3)
    >>> out.getvalue()
    'preparing voice: [##############################] 3/3\\n'
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import TextIO

__all__ = ["progress_bar"]


def progress_bar(label: str, enabled: bool = True, *, stream: TextIO | None = None) -> Callable[[int, int], None]:
    """``show(done, total)``: draws ``label: [####   ] done/total``; the line ends when ``done >= total``."""

    def show(done: int, total: int) -> None:
        out = stream if stream is not None else sys.stderr
        final, tty = done >= total, out.isatty()
        if not enabled or not (final or tty):
            return
        bar = "#" * int(30 * done / max(total, 1))
        line = f"{label}: [{bar:<30}] {done}/{total}"
        print(("\r" if tty else "") + line, end="\n" if final else "", file=out, flush=True)

    return show
