"""External commands as supervised children (a camera SDK binary, ``socat``).

The root starts the program with :class:`subprocess.Popen`. Before it
runs, the child asks the kernel for SIGKILL when the root dies
(``PR_SET_PDEATHSIG``), so even a SIGKILLed root leaves no orphan; it gets
its own process group, so Ctrl-C in the terminal reaches the root only and
the root stops children in order. Its exit is seen the moment it happens:
a pidfd (``os.pidfd_open``) is polled by the root IO loop, no timer. Its
stdout and stderr lines are logged under ``supervisor.child.<id>``.

Stopping sends SIGTERM (then SIGKILL, per the child's shutdown mode) to
the whole process group, so ``sh -c`` pipelines go too. A program that
leaves its process group is its own business.

Example::

    >>> ChildSpec("bridge", Command(["socat", "TCP-LISTEN:9000,fork", "UDP:robot:9000"]))  # doctest: +SKIP
"""

from __future__ import annotations

import contextlib
import logging
import os
import subprocess
from typing import TYPE_CHECKING

from actors import die_with_parent
from supervisor.exits import Exit, Reason
from supervisor.procs import Incarnation

if TYPE_CHECKING:
    from supervisor.spec import ChildSpec, Command
    from supervisor.tree import Tree

__all__ = ["CommandProcess"]

def _preexec(root_pid: int, nice: int | None, cpus: list[int] | None) -> None:
    """Runs in the forked child before exec: only async-signal-safe-ish syscalls here."""
    die_with_parent(root_pid)
    if nice:
        os.nice(nice)
    if cpus:
        os.sched_setaffinity(0, cpus)


class _Lines:
    """Forwards one pipe, line by line, to a logger (on the root IO loop)."""

    def __init__(self, tree: Tree, fd: int, log: logging.Logger, level: int, stream: str) -> None:
        self.tree, self.fd, self.log, self.level, self.stream = tree, fd, log, level, stream
        self.buf = b""
        os.set_blocking(fd, False)
        tree.loop.add(fd, self.on_readable)

    def on_readable(self) -> None:
        try:
            data = os.read(self.fd, 65536)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            self.close()
            return
        self.buf += data
        *lines, self.buf = self.buf.split(b"\n")
        for line in lines:
            self._emit(line)
        if len(self.buf) > 65536:  # a very long line: log it in pieces
            self._emit(self.buf)
            self.buf = b""

    def _emit(self, line: bytes) -> None:
        text = line.decode(errors="replace").rstrip("\r")
        if text:
            self.log.log(self.level, "%s", text, extra={"stream": self.stream})

    def close(self) -> None:
        if self.fd < 0:
            return
        if self.buf:
            self._emit(self.buf)
            self.buf = b""
        self.tree.loop.remove(self.fd)
        os.close(self.fd)
        self.fd = -1


class CommandProcess(Incarnation):
    """One run of an external program."""

    kind = "command"

    def __init__(self, tree: Tree, spec: ChildSpec, path: str) -> None:
        super().__init__(tree, spec, path)
        self.proc: subprocess.Popen[bytes] | None = None
        self.pidfd = -1
        self.readers: list[_Lines] = []

    @property
    def pid(self) -> int | None:
        return None if self.proc is None else self.proc.pid

    def start(self) -> None:
        cmd: Command = self.spec.start
        env = None if cmd.env is None else {**os.environ, **cmd.env}
        root = os.getpid()
        nice, cpus = self.spec.nice, list(self.spec.cpu_affinity or []) or None
        try:
            self.proc = subprocess.Popen(
                list(cmd.argv),
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                env=env,
                cwd=cmd.cwd,
                close_fds=True,
                start_new_session=True,
                preexec_fn=lambda: _preexec(root, nice, cpus),
            )
        except (OSError, subprocess.SubprocessError) as exc:
            self.cause = Exit(Reason.ERROR, None, f"cannot start {cmd.argv[0]!r}: {exc}")
            self._finish(None)
            return
        log = logging.getLogger(f"supervisor.child.{self.name}")
        assert self.proc.stdout is not None and self.proc.stderr is not None
        self.readers = [
            _Lines(self.tree, os.dup(self.proc.stdout.fileno()), log, cmd.stdout_level, "stdout"),
            _Lines(self.tree, os.dup(self.proc.stderr.fileno()), log, cmd.stderr_level, "stderr"),
        ]
        self.proc.stdout.close()
        self.proc.stderr.close()
        self.pidfd = os.pidfd_open(self.proc.pid)
        self.tree.loop.add(self.pidfd, self._on_pidfd)
        self._set_ready()  # a program is "started" once it runs, as OTP's start returning a pid

    def _on_pidfd(self) -> None:
        assert self.proc is not None
        code = self.proc.poll()
        if code is None:
            return
        self.tree.loop.remove(self.pidfd)
        os.close(self.pidfd)
        self.pidfd = -1
        self._finish(code)

    def _signal(self, sig: int) -> None:
        if self.proc is None or self.exited.done():
            return
        try:
            os.killpg(self.proc.pid, sig)
        except ProcessLookupError:
            with contextlib.suppress(ProcessLookupError):
                self.proc.send_signal(sig)

