"""Spawned actor processes: a fresh interpreter instead of a fork of the fork server.

A forked child inherits the root's memory, which is fast but carries state
that does not survive ``fork`` (a CUDA context is the usual one: a forked
child that touches it fails with CUDA's "initialization error"). A spawned
child runs ``python -m actors.spawn``, reads its process spec (msgpack, the
same data the fork server gets) from stdin, imports what it needs itself and
runs :func:`actors.child.child_main`. It dies with the root (PDEATHSIG).

A spec with ``"standby": True`` makes a warm standby: the actor is built,
its ``on_standby()`` runs, the root gets a ``["standby", name, pid]`` note,
and the process waits (no mailbox, no topics, no journal yet) for SIGUSR1,
on which it takes over as the actor's next incarnation (binds the mailbox,
so senders re-send what the dead one had not acknowledged), or SIGTERM, on
which it exits with status 0.

Example::

    info = system.start_process(spec, method="spawn", standby=True)   # doctest: +SKIP
    system.take_over(info)                                             # doctest: +SKIP
"""

from __future__ import annotations

import os
import signal
import sys

import msgpack

__all__ = ["main"]


def main() -> None:
    """Entry point of a spawned actor process (``python -m actors.spawn``)."""
    data = sys.stdin.buffer.read()
    spec = msgpack.unpackb(data)
    devnull = os.open(os.devnull, os.O_RDONLY)
    os.dup2(devnull, 0)
    os.close(devnull)
    from actors.child import TAKE_OVER

    if spec.get("standby"):
        # Blocked since birth (the root spawns a standby with them blocked; the mask survives exec)
        # and still before any thread exists (ZeroMQ's IO threads inherit the mask): only the
        # standby's sigwait receives them, and a take-over signal sent early waits for it.
        signal.pthread_sigmask(signal.SIG_BLOCK, {TAKE_OVER, signal.SIGTERM})
    else:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {TAKE_OVER, signal.SIGTERM})
    from actors.pdeathsig import die_with_parent

    die_with_parent(int(spec["root_pid"]))
    from actors.child import child_main

    code = 0
    try:
        child_main(spec)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":
    main()
