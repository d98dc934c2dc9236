"""``embagents logs NAME [-f]``: one actor's log lines, from its file in the run directory.

Every actor process (and the root, as ``root``) writes its lines to
``<run>/logs/NAME.log`` too, rotated at 5 MB with 3 old files kept
(:func:`actors.child.add_log_file`). ``-f`` follows the file across
rotations until Ctrl-C or the end of the run.

Example::

    $ embagents logs vision -n 2
    2026-11-23 23:40:01,112 [vision] INFO embagents.vision: detector ready
    2026-11-23 23:40:01,530 [vision] INFO embagents.component: active
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import deque

from actors import UnsafeFolder, pid_alive
from actors.child import LOG_BACKUPS, log_path
from embagents.cli.control import run_arguments
from supervisor.client import ControlError, pick_run

__all__ = ["arguments", "run"]

#: How often ``-f`` looks for new lines (a sleep, not a spin: an idle follow costs nothing).
FOLLOW_INTERVAL = 0.2


def arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", help="an actor of the run (or root)")
    parser.add_argument("-f", "--follow", action="store_true", help="keep printing new lines")
    parser.add_argument("-n", "--lines", type=int, help="only the last N lines")
    run_arguments(parser, None)


def _logs(folder: str) -> list[str]:
    """The actors with a log file in ``folder`` (the run's ``logs``)."""
    try:
        return sorted(f[:-4] for f in os.listdir(folder) if f.endswith(".log"))
    except FileNotFoundError:
        return []


def _follow(path: str, pos: int, pid: int) -> None:
    ino = os.stat(path).st_ino
    with open(path, errors="replace") as f:
        f.seek(pos)
        while pid_alive(pid):
            line = f.readline()
            if line:
                sys.stdout.write(line)
                continue
            sys.stdout.flush()
            time.sleep(FOLLOW_INTERVAL)
            try:
                st = os.stat(path)
            except FileNotFoundError:
                continue
            if st.st_ino != ino or st.st_size < f.tell():  # rotated: the new file from its start
                sys.stdout.write(f.read())
                _follow(path, 0, pid)
                return


def run(args: argparse.Namespace) -> int:
    """Print (and with ``-f`` follow) the log of actor ``args.name``; 1 with an error naming the known ones."""
    try:
        found = pick_run(args.run)
        folder = os.path.dirname(log_path(found["run_dir"], "root"))
        known = _logs(folder)
        if args.name not in known:  # only a file listed there: a name is never a path out of it
            raise ControlError(f"no log for {args.name!r} in run {found['run_id']}; "
                               f"logs: {', '.join(known) or 'none yet'}")
        path = log_path(found["run_dir"], args.name)
        old = [f"{path}.{i}" for i in range(LOG_BACKUPS, 0, -1) if os.path.exists(f"{path}.{i}")]
        lines: deque[str] = deque(maxlen=args.lines if args.lines else None)
        for p in [*old, path]:
            with open(p, errors="replace") as f:
                lines.extend(f)
                pos = f.tell()
        sys.stdout.writelines(lines)
        if args.follow:
            _follow(path, pos, int(found["pid"]))
    except (ControlError, UnsafeFolder) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except (KeyboardInterrupt, BrokenPipeError):
        pass
    return 0
