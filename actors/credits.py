"""Flow control and acknowledgements for ``keep="all"`` topics: how far a subscriber has read, in shared memory.

ZeroMQ's own back pressure (high-water marks on PUSH/PULL over ipc) stalls
for about a second at a time here (libzmq 4.3.5, measured in both
directions), so a keep-all subscription writes the sequence number of the
last message it has *handled* from each publisher in a small file it maps
(its mark file in the topic's folder): its acknowledgement. A publisher
keeps the messages it sent and that are not acknowledged yet (at most
``window`` of them), waiting when it is that far ahead, and re-sends them
to the next incarnation of a subscription that died (see
:mod:`actors.topics`). The table has a slot per publisher:
``(publisher id, last sequence number handled)``, 16 bytes each; after it,
the subscription's durable key (its identity across incarnations, empty for
none), NUL-padded.

Example::

    >>> import tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "sub")
    >>> board = CreditBoard.create(path, key="camera#0")
    >>> board.handled(publisher=7, seq=41)
    >>> board.handled(publisher=7, seq=42)
    >>> view = CreditView(path)
    >>> view.handled(publisher=7), view.key
    (42, 'camera#0')
"""

from __future__ import annotations

import mmap
import os
import struct

__all__ = ["KEY_BYTES", "SLOTS", "CreditBoard", "CreditView"]

#: Publishers one subscription keeps counts for at once (the oldest slot is reused after that).
SLOTS = 64
#: The most bytes of a durable key (UTF-8).
KEY_BYTES = 256
_SLOT = struct.Struct("<QQ")
_TABLE = SLOTS * _SLOT.size
_SIZE = _TABLE + KEY_BYTES


class CreditBoard:
    """The subscriber's side: the last sequence number handled per publisher."""

    def __init__(self, mm: mmap.mmap) -> None:
        self._mm = mm
        self._slot: dict[int, int] = {}  # publisher id -> slot index
        self._next = 0

    @classmethod
    def create(cls, path: str, key: str = "") -> CreditBoard:
        """Create the file at ``path`` (it must not exist) with ``key`` in it, and map it.

        The file is written under a hidden name and renamed into place, so a
        publisher that sees it sees it whole (its size and its key).
        """
        raw = key.encode()
        if len(raw) > KEY_BYTES:
            raise ValueError(f"a subscription key has at most {KEY_BYTES} bytes, got {len(raw)}: use a shorter name")
        d, name = os.path.split(path)
        tmp = os.path.join(d, f".{name}")
        fd = os.open(tmp, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o600)
        try:
            os.ftruncate(fd, _SIZE)
            mm = mmap.mmap(fd, _SIZE)
        finally:
            os.close(fd)
        mm[_TABLE:_TABLE + len(raw)] = raw
        try:
            os.link(tmp, path)  # like a rename, but fails if ``path`` exists
        finally:
            os.unlink(tmp)
        return cls(mm)

    def handled(self, publisher: int, seq: int) -> None:
        """Message ``seq`` of ``publisher`` was handled (so were its earlier ones)."""
        slot = self._slot.get(publisher)
        if slot is None:
            slot = self._slot[publisher] = self._next % SLOTS
            self._next += 1
            if len(self._slot) > SLOTS:  # a long-gone publisher's slot is taken over
                old = next(p for p, s in self._slot.items() if s == slot and p != publisher)
                del self._slot[old]
        _SLOT.pack_into(self._mm, slot * _SLOT.size, publisher, seq)

    def close(self) -> None:
        self._mm.close()


class CreditView:
    """The publisher's side: reads how far a subscriber has handled its messages, and its key."""

    def __init__(self, path: str) -> None:
        self._mm: mmap.mmap | None = None
        self._slot = -1
        self.key: str | None = None  # the subscription's durable key, if it has one
        try:
            fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
        except FileNotFoundError:
            return  # gone already: the subscriber died; the publisher stalls on it and drops
        try:
            if os.fstat(fd).st_size >= _SIZE:
                self._mm = mmap.mmap(fd, _SIZE, prot=mmap.PROT_READ)
        finally:
            os.close(fd)
        if self._mm is not None:
            self.key = bytes(self._mm[_TABLE:_SIZE]).rstrip(b"\0").decode(errors="replace") or None

    def handled(self, publisher: int) -> int:
        """The last sequence number of ``publisher`` the subscriber has handled (0 if none yet)."""
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
