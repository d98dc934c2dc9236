"""A small per-actor file that outlives the actor's process.

It holds the heartbeat (read by the supervisor to detect hangs), the
message being processed (so the next incarnation knows which message
crashed its predecessor: the poison-message count), and the lifecycle
state. It is an mmap of a file in the run directory: writing it costs a
memory store, and it survives SIGKILL.

Example::

    >>> import tempfile, os
    >>> j = Journal(os.path.join(tempfile.mkdtemp(), "a.journal"))
    >>> j.begin(b"sender", 7); j.inflight()
    (b'sender', 7)
    >>> j.end(); j.inflight() is None
    True
"""

from __future__ import annotations

import mmap
import os
import struct
import time

__all__ = ["Journal"]

_SIZE = 512
_HB = struct.Struct("<d")  # 0: heartbeat, CLOCK_MONOTONIC (system-wide on Linux)
_ID = struct.Struct("<QB64s")  # seq, ident length, ident
_INFLIGHT = 8
_CRASH = 96  # the message that killed the previous incarnation(s) ...
_CRASH_COUNT = struct.Struct("<I")  # ... and how many times
_CRASH_COUNT_AT = 180
_STATE_AT = 200  # lifecycle state, one byte
_INCARNATION = struct.Struct("<I")
_INCARNATION_AT = 204


class Journal:
    """The journal of one actor; both the actor and its supervisor open it."""

    def __init__(self, path: str) -> None:
        self.path = path
        fd = os.open(path, os.O_CREAT | os.O_RDWR, 0o600)
        try:
            if os.fstat(fd).st_size < _SIZE:
                os.ftruncate(fd, _SIZE)
            self.mm = mmap.mmap(fd, _SIZE)
        finally:
            os.close(fd)

    # -- heartbeat ----------------------------------------------------------
    def beat(self) -> None:
        _HB.pack_into(self.mm, 0, time.monotonic())

    def last_beat(self) -> float:
        return _HB.unpack_from(self.mm, 0)[0]

    # -- in-flight message --------------------------------------------------
    def begin(self, ident: bytes, seq: int) -> None:
        _ID.pack_into(self.mm, _INFLIGHT, seq, len(ident), ident[:64])

    def end(self) -> None:
        _ID.pack_into(self.mm, _INFLIGHT, 0, 0, b"")

    def inflight(self) -> tuple[bytes, int] | None:
        seq, n, ident = _ID.unpack_from(self.mm, _INFLIGHT)
        return (ident[:n], seq) if seq else None

    def crashed_message(self) -> tuple[bytes, int, int] | None:
        """(sender, seq, crash count) of the message that killed earlier incarnations."""
        seq, n, ident = _ID.unpack_from(self.mm, _CRASH)
        if not seq:
            return None
        return ident[:n], seq, _CRASH_COUNT.unpack_from(self.mm, _CRASH_COUNT_AT)[0]

    def on_restart(self) -> tuple[bytes, int, int] | None:
        """Called by a new incarnation: count the message its predecessor died on."""
        cur = self.inflight()
        if cur is not None:
            prev = self.crashed_message()
            count = prev[2] + 1 if prev is not None and prev[:2] == cur else 1
            _ID.pack_into(self.mm, _CRASH, cur[1], len(cur[0]), cur[0])
            _CRASH_COUNT.pack_into(self.mm, _CRASH_COUNT_AT, count)
            self.end()
        inc = _INCARNATION.unpack_from(self.mm, _INCARNATION_AT)[0] + 1
        _INCARNATION.pack_into(self.mm, _INCARNATION_AT, inc)
        return self.crashed_message()

    @property
    def incarnation(self) -> int:
        return _INCARNATION.unpack_from(self.mm, _INCARNATION_AT)[0]

    # -- lifecycle ----------------------------------------------------------
    def set_state(self, state: int) -> None:
        self.mm[_STATE_AT] = state

    def state(self) -> int:
        return self.mm[_STATE_AT]

    def close(self) -> None:
        self.mm.close()
