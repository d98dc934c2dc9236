"""A told message that raises ends the actor process at once, keeping its journal mark.

The mailbox writes a message's id to the journal before handling it, so a
process that dies while handling it lets the next incarnation count the
crash against that message; past ``poison_limit`` crashes the message is
dead-lettered and the actor keeps serving. The runtime clears that mark
when a told message raises a Python exception (its ``finally``), so such a
message would be delivered again and again, and only the restart intensity
would stop the loop. This spec hook (installed by the supervisor in every
actor it starts) makes an exception in a told message end the process
*inside* the handler: the mark stays, the poison count works for
exceptions as for segfaults. It also tells the root why, and waits until
that note is out, so the "crashed" event carries the exception (for a
failed ``on_start`` too).

Remove once ``actors.mailbox.Mailbox._handle`` keeps the journal mark when
a tell raises (see the supervisor README notes).

Example::

    >>> ChildSpec("parser", Parser, poison_limit=3)   # doctest: +SKIP
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import traceback
from typing import Any, NoReturn

import msgpack
import zmq

from actors import wire

__all__ = ["crash", "install"]


def crash(host: Any, exc: BaseException) -> NoReturn:
    """End this actor process with status 1, telling the root why."""
    logging.getLogger("actors").error("actor crashed: %s\n%s", exc, traceback.format_exc())
    with contextlib.suppress(Exception):
        s = host.rt.ctx.socket(zmq.DEALER)
        s.setsockopt(zmq.LINGER, 500)
        s.connect(f"ipc://{host.rt.run_dir}/_root.ctl")
        s.send(msgpack.packb(["failed", host.name, os.getpid(), f"{type(exc).__name__}: {exc}"]))
        s.close()
        host.rt.ctx.destroy(linger=0)  # waits (up to 500 ms) for the note only
    with contextlib.suppress(Exception):
        sys.stdout.flush()
        sys.stderr.flush()
    os._exit(1)


def install(host: Any, spec: dict[str, Any]) -> None:
    """Spec hook: wrap the mailbox handler and the start (outermost, after the other hooks)."""
    inner = host.mailbox.handler
    started = host.start

    def start() -> None:
        try:
            started()
        except Exception as exc:  # on_start or the lifecycle replay: say why before exiting
            crash(host, exc)

    host.start = start

    def handler(kind: int, body: Any) -> Any:
        try:
            return inner(kind, body)
        except Exception as exc:
            if kind != wire.TELL:
                raise
            crash(host, exc)

    host.mailbox.handler = handler
