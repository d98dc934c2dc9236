"""Flow control for ``keep="all"`` topics: how far a subscriber has read, in shared memory.

ZeroMQ's own back pressure (high-water marks on PUSH/PULL over ipc) stalls
for about a second at a time here (libzmq 4.3.5, measured in both
directions), so a keep-all subscription counts what it has *handled* from
each publisher in a small file it maps (its mark file in the topic's
folder), and a publisher keeps at most ``window`` messages in flight to it,
waiting when it is that far ahead. The table has a slot per publisher:
``(publisher id, messages handled)``, 16 bytes each.

Example::

    >>> import tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "sub")
    >>> board = CreditBoard.create(path)
    >>> board.handled(publisher=7)
    >>> board.handled(publisher=7)
    >>> CreditView(path).handled(publisher=7)
    2
"""

from __future__ import annotations

import mmap
import os
import struct

__all__ = ["CreditBoard", "CreditView", "SLOTS"]

#: Publishers one subscription keeps counts for at once (the oldest slot is reused after that).
SLOTS = 64
_SLOT = struct.Struct("<QQ")
_SIZE = SLOTS * _SLOT.size


class CreditBoard:
    """The subscriber's side: counts handled messages per publisher."""

    def __init__(self, mm: mmap.mmap) -> None:
        self._mm = mm
        self._slot: dict[int, int] = {}  # publisher id -> slot index
        self._count: dict[int, int] = {}
        self._next = 0

    @classmethod
    def create(cls, path: str, header: bytes = b"") -> CreditBoard:
        """Create the file at ``path`` (it must not exist) and map it."""
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o600)
        try:
            os.ftruncate(fd, _SIZE)
            mm = mmap.mmap(fd, _SIZE)
        finally:
            os.close(fd)
        return cls(mm)

    def handled(self, publisher: int) -> None:
        """One more message from ``publisher`` was handled."""
        n = self._count.get(publisher, 0) + 1
        self._count[publisher] = n
        slot = self._slot.get(publisher)
        if slot is None:
            slot = self._slot[publisher] = self._next % SLOTS
            self._next += 1
            if len(self._slot) > SLOTS:  # a long-gone publisher's slot is taken over
                old = next(p for p, s in self._slot.items() if s == slot and p != publisher)
                del self._slot[old], self._count[old]
        _SLOT.pack_into(self._mm, slot * _SLOT.size, publisher, n)

    def close(self) -> None:
        self._mm.close()


class CreditView:
    """The publisher's side: reads how many of its messages a subscriber has handled."""

    def __init__(self, path: str) -> None:
        self._mm: mmap.mmap | None = None
        self._slot = -1
        try:
            fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
        except FileNotFoundError:
            return  # gone already: the subscriber died; the publisher stalls on it and drops
        try:
            if os.fstat(fd).st_size >= _SIZE:
                self._mm = mmap.mmap(fd, _SIZE, prot=mmap.PROT_READ)
        finally:
            os.close(fd)

    def handled(self, publisher: int) -> int:
        """Messages from ``publisher`` the subscriber has handled (0 if it has none yet)."""
        mm = self._mm
        if mm is None:
            return 0
        if self._slot >= 0:
            pid, n = _SLOT.unpack_from(mm, self._slot * _SLOT.size)
            if pid == publisher:
                return int(n)
        for i in range(SLOTS):
            pid, n = _SLOT.unpack_from(mm, i * _SLOT.size)
            if pid == publisher:
                self._slot = i
                return int(n)
        return 0

    def close(self) -> None:
        if self._mm is not None:
            self._mm.close()
            self._mm = None
