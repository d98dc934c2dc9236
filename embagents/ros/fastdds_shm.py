"""Fast DDS's files in /dev/shm: which a process maps, and removing those of dead processes.

No rclpy here: the benchmark, which must not import rclpy, cleans up after
the ROS processes it SIGKILLs with the same rule as the bridge.

Example::

    >>> from embagents.ros.fastdds_shm import clean_zombie_fastdds_segments, mapped_fastdds_files
    >>> isinstance(mapped_fastdds_files(), set)
    True
    >>> clean_zombie_fastdds_segments(names=())   # only the named ones: none
    []
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
import time
from collections.abc import Collection, Iterator

__all__ = ["clean_zombie_fastdds_segments", "mapped_fastdds_files", "sweeping_dead_peers"]

SHM_DIR = "/dev/shm"
_SEGMENT = re.compile(r"^fastdds_(?:[0-9a-z]{16}|port\d{1,5})$")
_SUFFIX = re.compile(r"^(?:sem\.)?(fastdds_\w+?)(?:_el|_sl|_mutex)?$")


def mapped_fastdds_files(pid: int | str = "self") -> set[str]:
    """Names of the Fast DDS segments and ports process ``pid`` maps (empty if it is gone)."""
    try:
        with open(f"/proc/{pid}/maps") as f:
            names = {line.rsplit("/", 1)[1].strip() for line in f if "/dev/shm/fastdds_" in line}
    except OSError:
        return set()
    return {n for n in names if _SEGMENT.match(n)}


def clean_zombie_fastdds_segments(
    shm_dir: str = SHM_DIR, min_age: float = 10.0, names: Collection[str] | None = None
) -> list[str]:
    """Remove Fast DDS segments and ports whose owner process is gone; return their paths.

    Each DDS participant maps a ~0.5 MB ``fastdds_<16 hex>`` segment and
    listens on ``fastdds_port<N>`` ports (with a ``sem.fastdds_port<N>_mutex``),
    holding an flock on each one's ``_el`` (or, for a shared port, ``_sl``)
    file while alive. A SIGKILLed process cannot unlink them, so every
    supervisor restart of the bridge would leak some. Same rule as ``fastdds
    shm clean``, plus ``min_age`` so one being created right now (lock not
    yet taken) is never touched. A port with no lock file (only writers
    opened it: its listener is gone) is removed once no process maps it.
    ``names`` (any of a segment's or port's file names) limits the sweep to
    those: files known to be a dead process's need no ``min_age``.
    """
    removed: list[str] = []
    orphans: list[str] = []
    try:
        present = set(os.listdir(shm_dir))
    except OSError:
        return removed
    wanted = None if names is None else {m.group(1) for n in names if (m := _SUFFIX.match(n))}
    now = time.time()
    for name in sorted(present):
        if not _SEGMENT.match(name) or (wanted is not None and name not in wanted):
            continue
        locks = [os.path.join(shm_dir, name + s) for s in ("_el", "_sl") if name + s in present]
        seg = os.path.join(shm_dir, name)
        if not locks:
            orphans.append(seg)  # a port only writers opened (its listener is gone): judged below
            continue
        try:
            if any(now - os.stat(lock).st_mtime < min_age for lock in locks):
                continue
            with contextlib.ExitStack() as held:  # every lock stays taken until all are unlinked
                for lock in locks:
                    fd = held.enter_context(open(lock, "ab"))  # noqa: SIM115
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # fails while an owner lives
                for path in (seg, *locks):
                    os.unlink(path)
        except OSError:
            continue
        with contextlib.suppress(FileNotFoundError):
            os.unlink(os.path.join(shm_dir, f"sem.{name}_mutex"))  # ports only
        removed.append(seg)
    # A port without a lock file is garbage once no process maps it any more.
    orphans = [p for p in orphans if now - _mtime(p) >= min_age]
    if orphans:
        in_use = set().union(*(mapped_fastdds_files(pid) for pid in os.listdir("/proc") if pid.isdigit()))
        for seg in orphans:
            name = os.path.basename(seg)
            if name in in_use:
                continue
            with contextlib.suppress(FileNotFoundError):
                os.unlink(seg)
                removed.append(seg)
            with contextlib.suppress(FileNotFoundError):
                os.unlink(os.path.join(shm_dir, f"sem.{name}_mutex"))
    return removed


def _mtime(path: str) -> float:
    try:
        return os.stat(path).st_mtime
    except OSError:
        return time.time()


@contextlib.contextmanager
def sweeping_dead_peers(shm_dir: str = SHM_DIR) -> Iterator[None]:
    """On exit, remove the Fast DDS segments and ports made meanwhile whose owner is gone.

    For code that SIGKILLs plain rclpy peers (a bench's subscriber or
    server): they cannot unlink their files. Only files that appeared
    inside the block are looked at, so another run's live ones are safe.
    """
    def present() -> set[str]:
        try:
            return set(os.listdir(shm_dir))
        except OSError:
            return set()

    before = present()
    try:
        yield
    finally:
        clean_zombie_fastdds_segments(shm_dir, min_age=0, names=present() - before)
