"""A pre-imported, single-threaded fork server; actor processes are its children.

The root forks it once, before it creates any thread or socket of its own,
so every module the root had imported is already loaded: a new actor
process is one ``fork()`` away (milliseconds), and no spec ever needs
pickling (specs are msgpack, classes are found by ``module:QualName``).

It reports every child's exit the moment SIGCHLD arrives, removes the dead
child's shared-memory segments and subscription files, and when the root
goes away (its socket closes, even on SIGKILL) it kills every child and
removes the run's segments and directory: no orphans, no leaks.
"""

from __future__ import annotations

import contextlib
import gc
import glob
import logging
import os
import select
import shutil
import signal
import socket
import stat
import sys
import threading
import time
import traceback
from collections.abc import Callable
from typing import Any

import msgpack

from actors.pdeathsig import die_with_parent
from actors.shm import sweep
from actors.topics import mark_changed

__all__ = ["ForkServer", "cleanup_pid"]

_MAX = 1 << 20

#: The commands the root sends the fork server, and how many items each has.
_COMMANDS = {"spawn": 3, "kill": 3, "exit": 1}


def cleanup_pid(run_dir: str, prefix: str, pid: int) -> None:
    """Remove what dead process ``pid`` of the run left: shared memory, subscription and socket files."""
    sweep(f"{prefix}{pid}_")
    for path in glob.glob(os.path.join(run_dir, "topics", "*", f"{pid}-*")) + glob.glob(
            os.path.join(run_dir, "topics", "*", f".{pid}-*")):  # a mark killed while it was being made
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)
            mark_changed(os.path.dirname(path))  # its publishers stop sending to it
    for path in glob.glob(os.path.join(run_dir, f"s.{pid}-*")):
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)


def _serve(sock: socket.socket, run_dir: str, shm_run_prefix: str, child_main: Callable[[dict[str, Any]], None]) -> None:
    server_pid = os.getpid()
    # Keep only stdio and our socket: an inherited fd must not outlive the root through us.
    # /dev/null stays: it holds nothing open, and libraries imported before the fork keep
    # module-level handles on it (llama_cpp redirects its C output through one).
    # The others become /dev/null rather than closed: Python objects of the parent's (a file, an
    # mmap, a socket waiting in a garbage cycle) still own those numbers and close them when they
    # are collected, here or in a child, and a closed number would by then be a ZeroMQ socket's.
    devnull = os.stat(os.devnull).st_rdev
    null = os.open(os.devnull, os.O_RDWR | os.O_CLOEXEC)
    for fd in [int(f) for f in os.listdir("/proc/self/fd")]:
        if fd < 3 or fd in (sock.fileno(), null):
            continue
        with contextlib.suppress(OSError):  # the listing's own fd is closed by now
            st = os.fstat(fd)
            if stat.S_ISCHR(st.st_mode) and st.st_rdev == devnull:
                continue
            os.dup2(null, fd, inheritable=False)
    os.close(null)
    # What the root built is never garbage to an actor: frozen, the collector of every child skips it.
    # Walked, a late full collection in an actor of a big root (a test runner at the end of a suite)
    # touched every object, copied their pages and stalled the actor for half a second.
    gc.freeze()
    # Streams a test runner swapped in may sit on fds we just closed.
    sys.stdout = open(1, "w", buffering=1, closefd=False)  # noqa: SIM115
    sys.stderr = open(2, "w", buffering=1, closefd=False)  # noqa: SIM115
    rfd, wfd = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
    signal.set_wakeup_fd(wfd)
    signal.signal(signal.SIGCHLD, lambda *_: None)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the root's to handle
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    children: dict[int, str] = {}

    def send(msg: list[Any]) -> None:
        with contextlib.suppress(OSError):
            sock.send(msgpack.packb(msg))

    def reap() -> None:
        while True:
            try:
                pid, status = os.waitpid(-1, os.WNOHANG)
            except ChildProcessError:
                return
            if pid == 0:
                return
            code = os.waitstatus_to_exitcode(status)
            name = children.pop(pid, "?")
            cleanup_pid(run_dir, shm_run_prefix, pid)
            send(["exit", pid, code, name])

    while True:
        try:
            ready, _, _ = select.select([sock.fileno(), rfd], [], [])
        except InterruptedError:
            continue
        if rfd in ready:
            with contextlib.suppress(BlockingIOError):
                os.read(rfd, 4096)
            reap()
        if sock.fileno() in ready:
            try:
                data = sock.recv(_MAX)
            except OSError:
                data = b""
            if not data:
                break  # the root is gone
            # Only the root holds the other end of this socketpair; a frame that is not one of
            # its commands is still refused, not trusted (the server must outlive bad input).
            try:
                cmd = msgpack.unpackb(data)
                if not isinstance(cmd, list) or not cmd or cmd[0] not in _COMMANDS or len(cmd) != _COMMANDS[cmd[0]]:
                    raise ValueError(f"not a fork-server command: {cmd!r:.80}")
                if cmd[0] == "spawn" and not isinstance(cmd[2], dict):
                    raise ValueError("spawn takes [spawn, token, spec map]")
                if cmd[0] == "kill" and not (type(cmd[1]) is int and cmd[1] > 0 and type(cmd[2]) is int):
                    raise ValueError("kill takes [kill, pid > 0, signal]")
            except Exception as exc:
                print(f"fork server: dropped a bad command: {exc}", file=sys.stderr, flush=True)
                continue
            if cmd[0] == "spawn":
                token, spec = cmd[1], cmd[2]
                pid = os.fork()
                if pid == 0:
                    signal.set_wakeup_fd(-1)
                    os.close(rfd)
                    os.close(wfd)
                    sock.close()
                    signal.signal(signal.SIGCHLD, signal.SIG_DFL)
                    signal.signal(signal.SIGTERM, signal.SIG_DFL)
                    die_with_parent(server_pid)
                    code = 0
                    try:
                        child_main(spec)
                    except SystemExit as exc:
                        code = exc.code if isinstance(exc.code, int) else 1
                    except BaseException:
                        traceback.print_exc()
                        code = 1
                    finally:
                        with contextlib.suppress(Exception):
                            sys.stdout.flush()
                            sys.stderr.flush()
                        os._exit(code)
                children[pid] = spec.get("name", "?")
                send(["spawned", token, pid])
            elif cmd[0] == "kill":
                with contextlib.suppress(ProcessLookupError):
                    os.kill(cmd[1], cmd[2])
            elif cmd[0] == "exit":
                break
    # The root is gone or asked us to go: nothing of the run may survive us.
    for pid in list(children):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    for pid in list(children):
        with contextlib.suppress(ChildProcessError):
            os.waitpid(pid, 0)
    sweep(shm_run_prefix)
    shutil.rmtree(run_dir, ignore_errors=True)


class ForkServer:
    """The root's handle on its fork server."""

    def __init__(self, run_dir: str, shm_run_prefix: str, child_main: Callable[[dict[str, Any]], None]) -> None:
        parent, child = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        pid = os.fork()
        if pid == 0:
            parent.close()
            code = 0
            try:
                logging.shutdown = lambda *a, **k: None
                _serve(child, run_dir, shm_run_prefix, child_main)
            except BaseException:
                traceback.print_exc()
                code = 1
            os._exit(code)
        child.close()
        self.pid = pid
        self.sock = parent
        self.sock.setblocking(False)
        self._send_lock = threading.Lock()
        #: True once the server's end of the socket closed: it died (or was killed).
        self.lost = False

    def fileno(self) -> int:
        return self.sock.fileno()

    def send(self, msg: list[Any]) -> None:
        data = msgpack.packb(msg)
        with self._send_lock:  # any thread may send; the IO thread reads concurrently
            while True:
                try:
                    self.sock.send(data)
                    return
                except BlockingIOError:
                    select.select([], [self.sock], [], 1.0)

    def recv_all(self) -> list[list[Any]]:
        """Every note waiting from the server; on its end of the socket closing, sets :attr:`lost`."""
        out: list[list[Any]] = []
        while True:
            try:
                data = self.sock.recv(_MAX)
            except BlockingIOError:
                return out
            except OSError:
                data = b""
            if not data:  # the server is gone (its end closed): it will never say anything again
                self.lost = True
                return out
            out.append(msgpack.unpackb(data))

    def exit_status(self) -> str:
        """How the (lost) server ended, as far as ``waitpid`` can tell without waiting."""
        # Its socket closes as it dies: give the kernel a moment to make it a zombie we can read.
        for _ in range(100):
            try:
                pid, status = os.waitpid(self.pid, os.WNOHANG)
            except ChildProcessError:
                return "already reaped"
            if pid:
                break
            time.sleep(0.01)
        else:
            return "still running, its socket closed"
        if os.WIFSIGNALED(status):
            return f"killed by signal {os.WTERMSIG(status)}"
        return f"exit code {os.waitstatus_to_exitcode(status)}"

    def close(self, timeout: float = 5.0) -> None:
        with contextlib.suppress(OSError):
            self.send(["exit"])
        self.sock.close()
        try:
            _wait_pid(self.pid, timeout)
        except ChildProcessError:
            pass


def _wait_pid(pid: int, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while True:
        done, _ = os.waitpid(pid, os.WNOHANG)
        if done:
            return
        if time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            return
        time.sleep(0.005)
