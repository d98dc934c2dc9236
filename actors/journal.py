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

_SIZE = 4096
_HB = struct.Struct("<d")  # 0: heartbeat, CLOCK_MONOTONIC (system-wide on Linux)
# seq, ident length, ident, and 0 while the message's frame is still being decoded, 1 once it is
# decoded (a frame that kills its decoder is dead-lettered without being decoded again)
_ID = struct.Struct("<QB64sB")
_INFLIGHT = 8
_DECODED_AT = _INFLIGHT + _ID.size - 1
_STATE_AT = 200  # lifecycle state, one byte
_INCARNATION = struct.Struct("<I")
_INCARNATION_AT = 204
# Messages that killed earlier incarnations, with how many times: several slots, so a
# crash on another message (a SIGKILL from outside, say) does not reset a poison's count.
_CRASH_SLOT = struct.Struct("<QB64sIB")  # seq, ident length, ident, count, 1 if the last crash was in its decoding
_CRASH_AT = 1024
_CRASH_SLOTS = 16
_CRASH_NEXT_AT = 1020  # next slot to overwrite when all are taken (u32)


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
    def begin(self, ident: bytes, seq: int, *, decoded: bool = True) -> None:
        """Message ``seq`` of ``ident`` is in flight (``decoded=False``: its frame is not decoded yet)."""
        _ID.pack_into(self.mm, _INFLIGHT, seq, len(ident), ident[:64], decoded)

    def decoded(self) -> None:
        """The in-flight message's frame decoded: a crash from now on is its handler's."""
        self.mm[_DECODED_AT] = 1

    def end(self) -> None:
        _ID.pack_into(self.mm, _INFLIGHT, 0, 0, b"", 1)

    def inflight(self) -> tuple[bytes, int] | None:
        seq, n, ident, _ = _ID.unpack_from(self.mm, _INFLIGHT)
        return (ident[:n], seq) if seq else None

    def crashes(self) -> dict[tuple[bytes, int], int]:
        """(sender, seq) -> how many incarnations died while handling that message."""
        out = {}
        for i in range(_CRASH_SLOTS):
            seq, n, ident, count, _ = _CRASH_SLOT.unpack_from(self.mm, _CRASH_AT + i * _CRASH_SLOT.size)
            if seq:
                out[(ident[:n], seq)] = count
        return out

    def undecodable(self) -> set[tuple[bytes, int]]:
        """The messages of :meth:`crashes` whose last crash came while their frame was decoded."""
        out = set()
        for i in range(_CRASH_SLOTS):
            seq, n, ident, _, decoding = _CRASH_SLOT.unpack_from(self.mm, _CRASH_AT + i * _CRASH_SLOT.size)
            if seq and decoding:
                out.add((ident[:n], seq))
        return out

    def forget_crash(self, ident: bytes, seq: int) -> None:
        """Drop a message from the crash table (it was dead-lettered)."""
        for i in range(_CRASH_SLOTS):
            at = _CRASH_AT + i * _CRASH_SLOT.size
            s, n, ident_b, _, _ = _CRASH_SLOT.unpack_from(self.mm, at)
            if s == seq and ident_b[:n] == ident:
                _CRASH_SLOT.pack_into(self.mm, at, 0, 0, b"", 0, 0)

    def on_restart(self) -> dict[tuple[bytes, int], int]:
        """Called by a new incarnation: count the message its predecessor died on."""
        cur = self.inflight()
        if cur is not None:
            ident, seq = cur
            decoding = not self.mm[_DECODED_AT]
            free = None
            for i in range(_CRASH_SLOTS):
                at = _CRASH_AT + i * _CRASH_SLOT.size
                s, n, ident_b, count, _ = _CRASH_SLOT.unpack_from(self.mm, at)
                if s == seq and ident_b[:n] == ident:
                    _CRASH_SLOT.pack_into(self.mm, at, seq, len(ident), ident[:64], count + 1, decoding)
                    break
                if not s and free is None:
                    free = at
            else:
                if free is None:  # all taken: overwrite round robin
                    nxt = _INCARNATION.unpack_from(self.mm, _CRASH_NEXT_AT)[0] % _CRASH_SLOTS
                    _INCARNATION.pack_into(self.mm, _CRASH_NEXT_AT, nxt + 1)
                    free = _CRASH_AT + nxt * _CRASH_SLOT.size
                _CRASH_SLOT.pack_into(self.mm, free, seq, len(ident), ident[:64], 1, decoding)
            self.end()
        inc = _INCARNATION.unpack_from(self.mm, _INCARNATION_AT)[0] + 1
        _INCARNATION.pack_into(self.mm, _INCARNATION_AT, inc)
        return self.crashes()

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
