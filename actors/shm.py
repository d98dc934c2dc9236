"""Large arrays through POSIX shared memory (``/dev/shm``), written once.

A sender's :class:`ShmPool` copies an array into a segment it owns and the
frame carries a small handle; a receiver's :class:`ShmReader` maps the
segment and returns a read-only numpy view, without copying.

Lifetime is explicit:

* mailbox messages (tell / ask / reply): a segment stays reserved until the
  message is acknowledged *and* every view a receiver made of it has been
  released (the receiver reports it when the view is garbage collected), or
  the receiving process is gone. Then the pool reuses it, pages still hot.
* topics: the publisher keeps a ring per topic and reuses a segment only
  after ``ring`` newer frames *and* ``min_age`` seconds; a subscriber that
  maps a reused segment gets :class:`~actors.errors.StaleFrame` (the frame
  is dropped, as sensor data may be). Copy a frame to keep it longer.
* forwarded topic frames: a subscriber may pass a received topic frame on to
  a third process as its handle, not a copy (``Codec.encode(forward=True)``:
  a camera frame to a detector is written once, by the camera). The ring's
  rule still holds, so whoever uses a forwarded frame checks it afterwards
  with :meth:`ShmReader.unchanged`: a frame its publisher reused meanwhile
  may be torn, and what was computed from it is dropped.
* segment names carry the run and the owner pid (``ea<run>_<pid>_<n>r<random>``),
  so whoever reaps a dead process removes its segments with :func:`sweep`, and
  the run's end removes all of them. The random part keeps another local user,
  who can list ``/dev/shm``, from taking the next name first (a name that is
  taken anyway is retried with a new one).
* a reader maps only segments of its own run (``ShmReader(prefix=...)``),
  owned by its own user and not writable by group or others (checked once,
  when it first maps a segment); anything else is a corrupt frame: logged
  and dropped by whoever decodes it.

Example::

    >>> pool, reader = ShmPool("eadoc_1_"), ShmReader()
    >>> h = pool.put(np.arange(100_000, dtype=np.int32))
    >>> int(reader.view(h, None)[-1])
    99999
    >>> pool.close()
"""

from __future__ import annotations

import math
import mmap
import os
import re
import secrets
import stat
import struct
import time
import weakref
from collections import OrderedDict, deque
from collections.abc import Callable
from typing import Any

import numpy as np

from actors.errors import CorruptFrame, StaleFrame

__all__ = ["SHM_DIR", "ShmPool", "ShmReader", "sweep"]

#: What a segment name looks like (see ``actors.runtime.shm_prefix``); anything else is refused.
_NAME_RE = re.compile(r"^ea[A-Za-z0-9]+_[0-9]+_[0-9A-Za-z]+$")

SHM_DIR = "/dev/shm"
_HEADER = 64  # magic + generation; data starts cache-line aligned
_MAGIC = 0x45415348  # "EASH"
_HDR = struct.Struct("<IIQ")
_PAGE = mmap.PAGESIZE
#: New names tried when a segment's name is taken (by someone else: ours are never reused).
_NAME_TRIES = 16


def _token() -> str:
    """The unpredictable part of a segment name."""
    return secrets.token_hex(5)


class _Segment:
    __slots__ = ("name", "size", "mm", "gen", "msg_refs", "views", "stamp")

    def __init__(self, fd: int, name: str, size: int) -> None:
        self.name = name
        self.size = size
        try:
            os.ftruncate(fd, size)
            self.mm = mmap.mmap(fd, size, flags=mmap.MAP_SHARED | getattr(mmap, "MAP_POPULATE", 0))
        finally:
            os.close(fd)
        self.gen = 0
        self.msg_refs = 0  # messages (unacked or in flight) that refer to it
        self.views: dict[Any, int] = {}  # receiver link -> views not yet released
        self.stamp = 0.0

    def write(self, arr: np.ndarray) -> None:
        self.gen += 1
        _HDR.pack_into(self.mm, 0, _MAGIC, 0, self.gen)
        dst = np.frombuffer(self.mm, dtype=np.uint8, count=arr.nbytes, offset=_HEADER)
        np.copyto(dst.view(arr.dtype).reshape(arr.shape), arr, casting="no")
        self.stamp = time.monotonic()

    def busy(self) -> bool:
        return self.msg_refs > 0 or any(self.views.values())

    def unlink(self) -> None:
        try:
            os.unlink(os.path.join(SHM_DIR, self.name))
        except FileNotFoundError:
            pass
        try:
            self.mm.close()
        except BufferError:  # a local view still exists; the kernel frees it with the view
            pass


class ShmPool:
    """The segments one process writes; names start with ``prefix``.

    ``put`` reserves a segment for a mailbox message; :meth:`sent`,
    :meth:`acked` and :meth:`released` drive its reuse. ``put_ring`` is the
    topic variant.
    """

    def __init__(self, prefix: str, *, max_free_bytes: int = 1 << 30) -> None:
        self.prefix = prefix
        self._seq = 0
        self._segs: dict[str, _Segment] = {}
        self._free: list[_Segment] = []
        self._rings: dict[str, deque[_Segment]] = {}
        self.max_free_bytes = max_free_bytes
        self._local_released: deque[str] = deque()  # appended from any thread (GC)

    def _new(self, nbytes: int) -> _Segment:
        size = _HEADER + -(-nbytes // _PAGE) * _PAGE
        for _ in range(_NAME_TRIES):
            self._seq += 1
            name = f"{self.prefix}{self._seq}r{_token()}"
            try:
                fd = os.open(os.path.join(SHM_DIR, name), os.O_CREAT | os.O_EXCL | os.O_RDWR | os.O_NOFOLLOW, 0o600)
            except FileExistsError:
                continue  # someone made it first: never use (or unlink) a segment that is not ours
            seg = _Segment(fd, name, size)
            self._segs[seg.name] = seg
            return seg
        raise FileExistsError(f"{_NAME_TRIES} new shared-memory names under {SHM_DIR}/{self.prefix}* were all taken; "
                              f"another process is creating segments with this run's names: look at `ls -l {SHM_DIR}`")

    def local_release(self, name: str) -> None:
        """A local view of our own segment died (any thread): applied at the next put."""
        self._local_released.append(name)

    def _apply_local_releases(self) -> None:
        while self._local_released:
            self.released(self._local_released.popleft(), LOCAL)

    def _take_free(self, nbytes: int) -> _Segment | None:
        self._apply_local_releases()
        best = None
        for seg in self._free:
            if _HEADER + nbytes <= seg.size <= 2 * (_HEADER + nbytes) + _PAGE:
                if best is None or seg.size < best.size:
                    best = seg
        if best is not None:
            self._free.remove(best)
        return best

    @staticmethod
    def _handle(seg: _Segment, arr: np.ndarray) -> list[Any]:
        return [seg.name, seg.gen, _HEADER, arr.dtype.str, list(arr.shape)]

    def put(self, arr: np.ndarray) -> list[Any]:
        """Copy ``arr`` into a reserved segment and return its handle."""
        arr = np.ascontiguousarray(arr)
        seg = self._take_free(arr.nbytes) or self._new(arr.nbytes)
        seg.write(arr)
        seg.msg_refs += 1
        return self._handle(seg, arr)

    def put_ring(self, key: str, arr: np.ndarray, *, ring: int = 8, min_age: float = 0.5) -> list[Any]:
        """Copy ``arr`` into topic ``key``'s ring (see the module docstring)."""
        arr = np.ascontiguousarray(arr)
        q = self._rings.setdefault(key, deque())
        seg = None
        if q and (len(q) >= 4 * ring or (len(q) >= ring and time.monotonic() - q[0].stamp >= min_age)):
            seg = q.popleft()
            if seg.size < _HEADER + arr.nbytes or seg.size > 2 * (_HEADER + arr.nbytes) + _PAGE:
                self._drop(seg)
                seg = None
        if seg is None:
            seg = self._new(arr.nbytes)
        seg.write(arr)
        q.append(seg)
        return self._handle(seg, arr)

    # -- mailbox accounting -------------------------------------------------
    def sent(self, names: list[str], link: Any) -> None:
        """A message referring to ``names`` went out on ``link`` (one view each)."""
        for n in names:
            seg = self._segs.get(n)
            if seg is not None:
                seg.views[link] = seg.views.get(link, 0) + 1

    def acked(self, names: list[str]) -> None:
        """The message referring to ``names`` is done (acknowledged or abandoned)."""
        for n in names:
            seg = self._segs.get(n)
            if seg is not None:
                seg.msg_refs -= 1
                self._maybe_free(seg)

    def released(self, name: str, link: Any) -> None:
        """A receiver on ``link`` dropped its view of ``name``."""
        seg = self._segs.get(name)
        if seg is not None and seg.views.get(link, 0) > 0:
            seg.views[link] -= 1
            self._maybe_free(seg)

    def link_lost(self, link: Any) -> None:
        """The process behind ``link`` is gone: its views went with it."""
        for seg in list(self._segs.values()):
            if seg.views.pop(link, None):
                self._maybe_free(seg)

    def _maybe_free(self, seg: _Segment) -> None:
        if seg.busy() or seg in self._free or any(seg in q for q in self._rings.values()):
            return
        seg.views.clear()
        self._free.append(seg)
        # Keep hot segments for reuse, but bound what idles in /dev/shm.
        while sum(s.size for s in self._free) > self.max_free_bytes:
            self._drop(self._free.pop(0))

    def _drop(self, seg: _Segment) -> None:
        self._segs.pop(seg.name, None)
        seg.unlink()

    @property
    def segment_count(self) -> int:
        return len(self._segs)

    def close(self) -> None:
        """Unlink every segment this pool created."""
        for seg in list(self._segs.values()):
            seg.unlink()
        self._segs.clear()
        self._free.clear()
        self._rings.clear()


LOCAL = "local"  # the pool's own process, as a viewer of its own segments


class ShmReader:
    """Maps segments written by other processes; caches recent mappings.

    With ``pool`` (this process's own), a frame that comes back to its owner
    (an actor returned the array it was sent) is a view of the owner's own
    segment, counted as a local view so the pool does not reuse it under it.
    ``prefix``: the run's segment prefix; a segment named otherwise, owned by
    another user or writable by group or others is refused (:class:`CorruptFrame`).
    """

    def __init__(self, max_cached: int = 128, pool: ShmPool | None = None, prefix: str = "ea") -> None:
        self.prefix = prefix
        self._uid = os.getuid()
        self._maps: OrderedDict[str, mmap.mmap] = OrderedDict()
        self.max_cached = max_cached
        self.pool = pool
        self._origins: dict[int, list[Any]] = {}  # data address of a received frame -> its handle
        self._forwardable: set[int] = set()  # ...of those, the topic frames (no release owed to anyone)

    def _map(self, name: str) -> mmap.mmap:
        mm = self._maps.get(name)
        if mm is not None:
            self._maps.move_to_end(name)
            return mm
        if not isinstance(name, str) or not _NAME_RE.match(name):
            raise CorruptFrame(f"not a shared-memory frame name: {name!r}")
        if not name.startswith(self.prefix):
            raise CorruptFrame(f"shared-memory frame {name} is not of this run (its names start with {self.prefix})")
        try:
            # O_NONBLOCK: a FIFO planted under a valid-looking name must not block us.
            fd = os.open(os.path.join(SHM_DIR, name), os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
        except FileNotFoundError:
            raise StaleFrame(f"shared-memory frame {name} is gone (its writer released or died)") from None
        try:
            st = os.fstat(fd)
            if not stat.S_ISREG(st.st_mode):
                raise CorruptFrame(f"shared-memory frame {name} is not a regular file")
            if st.st_uid != self._uid or st.st_mode & 0o022:
                # Another user's segment under a name of ours: its owner could change it under us.
                raise CorruptFrame(f"refused shared-memory frame {name}: owned by uid {st.st_uid} with mode "
                                   f"{oct(stat.S_IMODE(st.st_mode))[2:]}; a run maps only its own user's 0600 segments")
            mm = mmap.mmap(fd, 0, prot=mmap.PROT_READ)
        finally:
            os.close(fd)
        self._maps[name] = mm
        while len(self._maps) > self.max_cached:
            self._maps.popitem(last=False)  # live views keep their mapping alive
        return mm

    def view(self, handle: list[Any], on_release: Callable[[str, int], None] | None) -> np.ndarray:
        """A read-only view of the frame ``handle``; ``on_release`` runs when it is collected."""
        name, gen, offset, dtype, shape = handle
        mm = self._map(name)
        magic, _, cur = _HDR.unpack_from(mm, 0)
        if magic != _MAGIC or cur != gen:
            raise StaleFrame(f"shared-memory frame {name} was reused before it was read")
        dt = np.dtype(dtype)
        count = math.prod(shape)
        arr = np.frombuffer(mm, dtype=dt, count=count, offset=offset)
        addr = arr.__array_interface__["data"][0]
        self._origins[addr] = handle
        # Only this view's own entry goes with it: a newer view of the same segment may have replaced it.
        weakref.finalize(arr.base, self._forget_origin, addr, handle)
        pool = self.pool
        if on_release is None and (pool is None or not name.startswith(pool.prefix)):
            # Nobody counts views of it (a topic frame): the ring's rule decides its life, wherever it goes.
            self._forwardable.add(addr)
        else:
            self._forwardable.discard(addr)
        if pool is not None and name.startswith(pool.prefix):
            pool.sent([name], LOCAL)  # our own segment came back: a local view now holds it
            weakref.finalize(arr.base, pool.local_release, name)
            return arr.reshape(shape)
        if on_release is not None:
            # arr.base is the buffer numpy made for this call: every view derived from the
            # returned array keeps it alive, so it dies exactly when the last view does.
            # (Finalizing a memoryview we pass in does not work: NumPy 2 wraps it anew.)
            weakref.finalize(arr.base, on_release, name, gen)
        return arr.reshape(shape)

    def _forget_origin(self, addr: int, handle: list[Any]) -> None:
        if self._origins.get(addr) is handle:
            del self._origins[addr]
            self._forwardable.discard(addr)

    def origin(self, arr: np.ndarray, *, forwardable: bool = False) -> list[Any] | None:
        """The handle of the received frame ``arr`` is, whole and unchanged in shape; else None.

        ``forwardable``: only a topic frame of another process (one a third
        process may map by its handle; see the module docstring).
        """
        addr = arr.__array_interface__["data"][0]
        handle = self._origins.get(addr)
        if handle is None or arr.dtype.str != handle[3] or list(arr.shape) != list(handle[4]):
            return None
        if forwardable and addr not in self._forwardable:  # a mailbox frame: its sender counts views
            return None
        return handle if arr.flags.c_contiguous else None

    def unchanged(self, handle: list[Any]) -> bool:
        """Whether the frame ``handle`` names still holds what was sent (its writer has not reused it).

        A writer stamps the new generation before it writes a byte, so a frame
        still of its generation after it was used was whole while it was used.
        A segment that is gone (its writer died) counts as changed: nobody can say.
        """
        try:
            mm = self._map(handle[0])
        except StaleFrame:
            return False
        return bool(_HDR.unpack_from(mm, 0)[2] == handle[1])

    def forget(self, name: str) -> None:
        self._maps.pop(name, None)

    def close(self) -> None:
        self._maps.clear()


def sweep(prefix: str) -> int:
    """Unlink every segment whose name starts with ``prefix``; return how many."""
    n = 0
    try:
        names = os.listdir(SHM_DIR)
    except FileNotFoundError:
        return 0
    for f in names:
        if f.startswith(prefix):
            try:
                os.unlink(os.path.join(SHM_DIR, f))
                n += 1
            except (FileNotFoundError, PermissionError):
                pass  # gone already, or another user's (planted under our names: not ours to remove)
    return n
