"""Talking to a live run from another terminal: what ``embagents status|restart|stop`` use.

:func:`find_runs` lists the runs announced in :func:`supervisor.control.runs_dir`
(dropping announcements whose process is gone; a folder that is not private
to this user is refused with :class:`actors.UnsafeFolder`); :class:`ControlClient`
keeps one connection to a run's control endpoint for many requests (each with
its deadline and an id, so a late answer to an earlier request is never taken
for the answer to this one); :func:`request` sends one control request (see
:mod:`supervisor.control`) and returns the answer;
:func:`format_status_table` renders status rows; :func:`control` runs one
command and prints its outcome (``embagents status|restart|stop`` call it).
:func:`main` is a small command line over them (``python -m supervisor.client status --json``).

Example::

    run = pick_run()
    print(format_status_table(request(run["run_dir"], {"cmd": "status"})["rows"]))

prints::

    NAME    SUPERVISOR  KIND   STATUS   LIFECYCLE  PID    RESTARTS  UPTIME  CPU%  RSS MB  MAILBOX  MSG/S
    camera  root        actor  running  active     41822         0  3m12s    4.0    61.2        0   30.0
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import os
import sys
import threading
import time
from collections.abc import Sequence
from types import TracebackType
from typing import Any

import msgpack
import zmq

from actors import UnsafeFolder, check_folder, pid_alive
from actors.app import app_name
from supervisor.control import control_endpoint, runs_dir

__all__ = ["ControlClient", "ControlError", "control", "find_runs", "format_status_table", "main", "pick_run",
           "request", "wait_ready"]


class ControlError(RuntimeError):
    """The run could not be reached, or refused the request; ``reply`` is its answer (None when there was none)."""

    def __init__(self, message: str, reply: dict[str, Any] | None = None) -> None:
        super().__init__(message)
        self.reply = reply


def find_runs() -> list[dict[str, Any]]:
    """The live runs of this user, oldest first (stale announcements are removed)."""
    folder = runs_dir()
    try:
        names = sorted(os.listdir(folder))
    except FileNotFoundError:
        return []
    runs = []
    for fn in names:
        if not fn.endswith(".json"):
            continue
        path = os.path.join(folder, fn)
        try:
            with open(path) as f:
                info = json.load(f)
        except (OSError, ValueError):
            continue
        if not pid_alive(int(info.get("pid", 0))) or not os.path.isdir(info.get("run_dir", "")):
            with contextlib.suppress(OSError):
                os.unlink(path)  # its root died without cleaning up (SIGKILL)
            continue
        check_folder(info["run_dir"], create=False)  # its control socket must be this user's alone
        runs.append(info)
    runs.sort(key=lambda r: r.get("started", 0))
    return runs


def pick_run(which: str | None = None) -> dict[str, Any]:
    """The run named by ``which`` (run id, system name or pid), or the only live run."""
    runs = find_runs()
    if which is not None:
        runs = [r for r in runs if which in (r.get("run_id"), r.get("system"), str(r.get("pid")))]
    if not runs:
        raise ControlError(
            f"no live {app_name()} run found" + (f" matching {which!r}" if which else "")
            + f" (looked in {runs_dir()}); start one with: {app_name()} supervise system.py"
        )
    if len(runs) > 1:
        listing = ", ".join(f"{r['run_id']} ({r.get('system')}, pid {r.get('pid')})" for r in runs)
        raise ControlError(f"several live runs: {listing}; pick one with --run RUN_ID")
    return runs[0]


class ControlClient:
    """One run's control endpoint, connected once for many requests; safe to share between threads.

    Each thread gets its own DEALER socket (a ZeroMQ socket belongs to one
    thread). Every request carries ``deadline`` (``time.monotonic()`` + its
    timeout: the root does not start it later) and ``id`` (answers to requests
    this client gave up on are recognised and dropped).

    Example::

        with ControlClient(pick_run()["run_dir"]) as c:
            rows = c.request({"cmd": "status"})["rows"]
    """

    def __init__(self, run_dir: str, timeout: float = 5.0) -> None:
        self.run_dir, self.timeout = run_dir, timeout
        self._ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context.instance()
        self._local = threading.local()
        self._socks: list[zmq.Socket[bytes]] = []
        self._lock = threading.Lock()
        self._ids = itertools.count(1)
        self._closed = False

    def _sock(self) -> zmq.Socket[bytes]:
        if self._closed:
            raise ControlError(f"this client of the run at {self.run_dir} is closed")
        s: zmq.Socket[bytes] | None = getattr(self._local, "sock", None)
        if s is None:
            with self._lock:
                s = self._ctx.socket(zmq.DEALER)
                s.setsockopt(zmq.LINGER, 0)
                s.connect(control_endpoint(self.run_dir))
                self._socks.append(s)
            self._local.sock = s
        return s

    def request(self, msg: dict[str, Any], timeout: float | None = None) -> dict[str, Any]:
        """Send ``msg``; its answer (a dict). :class:`ControlError` if none comes within ``timeout`` or it says no."""
        timeout = self.timeout if timeout is None else timeout
        sock, rid = self._sock(), next(self._ids)
        deadline = time.monotonic() + timeout
        sock.send_multipart([b"", msgpack.packb({**msg, "id": rid, "deadline": deadline})])
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or not sock.poll(int(left * 1000) + 1):
                raise ControlError(f"no answer from the run at {self.run_dir} within {timeout:g} s "
                                   "(is it still running? a slow command needs a longer --timeout); "
                                   "if the run had not started it yet, it will not")
            reply = msgpack.unpackb(sock.recv_multipart()[-1])
            if isinstance(reply, dict) and reply.get("id") == rid:
                break  # else: the late answer to a request this thread gave up on
        if not reply.get("ok"):
            raise ControlError(reply.get("error", "the run refused the request"), reply)
        return reply

    def close(self) -> None:
        """Close every thread's socket; call it when no request is in flight (each socket is its thread's)."""
        with self._lock:
            self._closed = True
            for s in self._socks:
                s.close()
            self._socks.clear()

    def __enter__(self) -> ControlClient:
        return self

    def __exit__(self, *exc: type[BaseException] | BaseException | TracebackType | None) -> None:
        self.close()


def request(run_dir: str, msg: dict[str, Any], timeout: float = 5.0) -> dict[str, Any]:
    """Send one control request to the run at ``run_dir``; returns its answer (a dict).

    Raises :class:`ControlError` if there is no answer within ``timeout``
    seconds (the root then no longer starts it) or the run answered ``ok: false``.
    """
    with ControlClient(run_dir, timeout) as client:
        return client.request(msg)


#: How often :func:`wait_ready` looks for a run that has not announced itself yet.
_LOOK_EVERY_S = 0.1


def wait_ready(run: str | None = None, timeout: float = 60.0) -> dict[str, Any]:
    """Block until the run (see :func:`pick_run`) is ready; returns its announcement.

    A run that has not announced itself yet is looked for every 0.1 s; once
    found, one ``wait_ready`` request blocks until the run answers it.
    Raises :class:`ControlError` after ``timeout`` seconds.
    """
    deadline = time.monotonic() + timeout
    while True:
        try:
            picked = pick_run(run)
            break
        except ControlError as exc:
            if "several live runs" in str(exc) or time.monotonic() + _LOOK_EVERY_S > deadline:
                raise
            time.sleep(_LOOK_EVERY_S)
    try:
        request(picked["run_dir"], {"cmd": "wait_ready"}, max(0.001, deadline - time.monotonic()))
    except ControlError as exc:
        if "no answer" in str(exc) or "not ready yet" in str(exc):
            raise ControlError(f"run {picked['run_id']} ({picked.get('system')}) was not ready within {timeout:g} s") from None
        raise
    return picked


def _duration(s: float | None) -> str:
    if not s:
        return "-"
    s = int(s)
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    if s < 86400:
        return f"{s // 3600}h{s % 3600 // 60:02d}m"
    return f"{s // 86400}d{s % 86400 // 3600:02d}h"


def _num(v: Any, fmt: str = "{:.1f}") -> str:
    return "-" if v is None else fmt.format(v)


_COLUMNS = [
    # header, row -> text, right-aligned
    ("NAME", lambda r: r["name"], False),
    ("SUPERVISOR", lambda r: r["supervisor"], False),
    ("KIND", lambda r: r["kind"], False),
    ("STATUS", lambda r: r["status"], False),
    ("LIFECYCLE", lambda r: r.get("lifecycle") or "-", False),
    ("PID", lambda r: _num(r.get("pid"), "{}"), True),
    ("RESTARTS", lambda r: str(r.get("restarts", 0)), True),
    ("UPTIME", lambda r: _duration(r.get("uptime")), True),
    ("CPU%", lambda r: _num(r.get("cpu_percent")), True),
    ("RSS MB", lambda r: _num(r.get("rss_mb")), True),
    ("MAILBOX", lambda r: _num(r.get("mailbox"), "{}"), True),
    ("MSG/S", lambda r: _num(r.get("rate")), True),
    # messages its topic subscriptions lost (queue overflow, a publisher's HWM or stall, stale frames)
    ("DROPS", lambda r: _num(r.get("drops"), "{}"), True),
]


def format_status_table(rows: Sequence[dict[str, Any]]) -> str:
    """Status rows as an aligned text table (``-`` where a value is unknown)."""
    cells = [[h for h, _, _ in _COLUMNS]] + [[fn(r) for _, fn, _ in _COLUMNS] for r in rows]
    widths = [max(len(row[i]) for row in cells) for i in range(len(_COLUMNS))]
    lines = []
    for row in cells:
        parts = [c.rjust(w) if right else c.ljust(w) for c, w, (_, _, right) in zip(row, widths, _COLUMNS, strict=True)]
        lines.append("  ".join(parts).rstrip())
    for r in rows:  # an actor's own lines (a bridge's links), under the table
        lines += [f"{r['name']}: {line}" for line in ((r.get("detail") or {}).get("lines") or [])]
    return "\n".join(lines)


def control(cmd: str, *, run: str | None = None, timeout: float = 5.0, as_json: bool = False,
            name: str | None = None, wait_ready_s: float | None = None) -> int:
    """Run ``status`` (``as_json``: raw), ``restart`` (child ``name``) or ``stop`` against a live run.

    ``run`` picks the run (run id, system name or pid; default: the only
    live one). ``wait_ready_s``: ``status`` first waits (up to that many
    seconds) until the run is ready (see :func:`wait_ready`). Prints the
    outcome; returns the exit status (1 on error, with a JSON error object
    on stdout too when ``as_json``).
    """
    try:
        picked = wait_ready(run, wait_ready_s) if wait_ready_s is not None and cmd == "status" else pick_run(run)
        if cmd == "status":
            reply = request(picked["run_dir"], {"cmd": "status"}, timeout)
            if as_json:
                print(json.dumps(reply, indent=2))
            else:
                ready = "ready" if reply.get("ready") else "not ready yet"
                print(f"{reply['system']}  run {reply['run_id']}  pid {reply['pid']}  up {_duration(reply['uptime'])}  {ready}")
                print(format_status_table(reply["rows"]))
        elif cmd == "restart":
            reply = request(picked["run_dir"], {"cmd": "restart", "name": name}, timeout)
            print(f"restarted {name} (pid {reply['pid']})")
        elif cmd == "stop":
            request(picked["run_dir"], {"cmd": "stop"}, timeout)
            print(f"stopping run {picked['run_id']}")
        else:
            raise ControlError(f"unknown control command {cmd!r}: use status, restart or stop")
    except (ControlError, UnsafeFolder) as exc:
        if as_json:  # a script reading stdout gets JSON either way
            print(json.dumps({"ok": False, "error": str(exc)}))
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``status [--json] | restart NAME | stop`` against a live run; returns the exit status."""
    p = argparse.ArgumentParser(prog=app_name(), description=f"Control a live {app_name()} run.")
    p.add_argument("--run", help="run id, system name or pid (default: the only live run)")
    p.add_argument("--timeout", type=float, default=5.0)
    sub = p.add_subparsers(dest="cmd", required=True)
    st = sub.add_parser("status", help="a table of every supervised child")
    st.add_argument("--json", action="store_true", help="print the raw status as JSON")
    rs = sub.add_parser("restart", help="stop a child and start it again")
    rs.add_argument("name")
    sub.add_parser("stop", help="stop the run cleanly (children in reverse order)")
    args = p.parse_args(argv)
    return control(args.cmd, run=args.run, timeout=args.timeout, as_json=getattr(args, "json", False),
                   name=getattr(args, "name", None))


if __name__ == "__main__":
    sys.exit(main())
