"""The recorder: a supervised actor that writes topics to MCAP files, with rotation.

``embagents record`` asks the root to start one (:mod:`embagents.tools.root`).
It subscribes to each topic with the topic's own policy (keep-all topics
keep-all, so nothing of them is missing from the file), and writes every
message with the ``mcap`` library in chunks: each finished chunk goes
straight to the kernel (an unbuffered file), so a SIGKILL of the recorder
leaves a file readable up to its last chunk. A file is rotated when it
passes ``max_bytes`` or ``max_seconds``: ``out.mcap``, ``out.1.mcap``,
``out.2.mcap``... (``max_files`` keeps only the newest). A restarted
recorder never writes over its killed file: it goes on in the next one.
Each file is created afresh, owner-only (0600: a recording holds what the
robot saw and heard), never through a symbolic link, and locked (``flock``)
while written: a second recorder on the same file is refused.

Example (what the root starts)::

    ChildSpec("_record.1", (RecorderActor, ("/tmp/out.mcap", [["text", "embagents/String", "all", 10]], {})))
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import re
import time
from functools import partial
from typing import IO, Any, cast

from actors import Actor
from actors.codec import message_class
from embagents.tools.mcap_codec import kind_of

__all__ = ["RecorderActor", "RecordingLocked", "RecordingRefused", "lock_file", "refusal", "rotation_path", "rotation_files"]

log = logging.getLogger("embagents.record")
#: Default chunk size: a SIGKILL loses the open chunk (at most this much), never a finished one.
CHUNK_BYTES = 256 * 1024


class RecordingLocked(RuntimeError):
    """Another recorder writes this file."""


class RecordingRefused(RuntimeError):
    """Something is already at the recording's path (a file, a symbolic link): it is not written through."""


def rotation_path(base: str, index: int) -> str:
    """The ``index``-th file of a recording: ``out.mcap``, ``out.1.mcap``, ...

    >>> rotation_path("/tmp/out.mcap", 0), rotation_path("/tmp/out.mcap", 2)
    ('/tmp/out.mcap', '/tmp/out.2.mcap')
    """
    if index == 0:
        return base
    stem, ext = os.path.splitext(base)
    return f"{stem}.{index}{ext or '.mcap'}"


def rotation_files(base: str) -> list[str]:
    """The files of the recording at ``base`` that exist, in order."""
    return [p for _, p in _rotations(base)]


def _rotations(base: str) -> list[tuple[int, str]]:
    """``(index, path)`` of each file of the recording at ``base`` that exists, in order."""
    stem, ext = os.path.splitext(os.path.basename(base))
    folder = os.path.dirname(os.path.abspath(base))
    pattern = re.compile(rf"^{re.escape(stem)}\.(\d+){re.escape(ext or '.mcap')}$")
    found = [(0, base)] if os.path.exists(base) else []
    with contextlib.suppress(FileNotFoundError):
        for fn in os.listdir(folder):
            m = pattern.match(fn)
            if m:
                found.append((int(m.group(1)), os.path.join(folder, fn)))
    return sorted(found)


def lock_file(path: str) -> int:
    """Create ``path`` (owner-only, 0600) for writing and lock it.

    ``O_EXCL | O_NOFOLLOW``: a file or link already there is never written
    through (a link another user left in ``/tmp`` would make us write where it
    points); ``--overwrite`` unlinks the old files before the recorder starts.
    RecordingLocked if another recorder holds it, RecordingRefused for anything
    else already at the path.
    """
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
    except FileExistsError:
        raise refusal(path) from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:  # made by us an instant ago: only a recorder racing us for it holds it
        os.close(fd)
        raise RecordingLocked(f"{path} is being recorded by another `embagents record`; "
                              "stop that one or record to another file (-o)") from None
    return fd


def refusal(path: str) -> RuntimeError:
    """Why an existing ``path`` (a link, a file being recorded, a file) is not recorded to."""
    if os.path.islink(path):
        return RecordingRefused(f"{path} is a symbolic link (to {os.readlink(path)!r}); a recording is never "
                                "written through a link: remove it or record to another file (-o)")
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)  # a FIFO does not block us
    except OSError:
        fd = -1
    if fd >= 0:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return RecordingLocked(f"{path} is being recorded by another `embagents record`; "
                                   "stop that one or record to another file (-o)")
        finally:
            os.close(fd)
    return RecordingRefused(f"{path} exists; pass --overwrite to replace it or choose another -o")


class _Through:
    """A file stream whose every write reaches the kernel at once, whole (a SIGKILL loses no written record).

    Not an ``io.RawIOBase``: the mcap Writer would wrap one in a buffer.
    """

    def __init__(self, fd: int) -> None:
        self.fd, self.pos = fd, 0

    def write(self, data: bytes | memoryview) -> int:
        view = memoryview(data)
        while view:
            view = view[os.write(self.fd, view):]
        self.pos += len(data)
        return len(data)

    def tell(self) -> int:
        return self.pos

    def flush(self) -> None:
        pass

    def close(self) -> None:
        os.close(self.fd)


class _File:
    """One MCAP file being written: its writer, channels and size."""

    def __init__(self, path: str, compression: str, chunk_bytes: int = CHUNK_BYTES) -> None:
        from mcap.writer import CompressionType, Writer

        self.path = path
        self.fd = lock_file(path)
        self.stream = _Through(self.fd)
        # The Writer's annotation says IO; it calls only write, tell, flush and close, which _Through has.
        self.writer = Writer(cast(IO[bytes], self.stream), chunk_size=chunk_bytes, compression=CompressionType[compression.upper()])
        self.writer.start(profile="", library="embagents")
        self.channels: dict[str, int] = {}
        self.schemas: dict[str, int] = {}
        self.opened = time.monotonic()
        self.messages = 0

    def channel(self, topic: str, cls: type | None) -> int:
        ch = self.channels.get(topic)
        if ch is None:
            kind = kind_of(cls)
            sid = self.schemas.get(kind.schema_name)
            if sid is None:
                sid = self.schemas[kind.schema_name] = self.writer.register_schema(
                    kind.schema_name, kind.schema_encoding, kind.schema_data)
            ch = self.channels[topic] = self.writer.register_channel(topic, kind.message_encoding, sid)
        return ch

    def close(self) -> None:
        self.writer.finish()
        self.stream.close()  # releases the lock


class RecorderActor(Actor):
    """Records ``topics`` (``[name, wire type or "", keep, queue_size]``) to ``path``; see the module doc."""

    def __init__(self, path: str, topics: list[list[Any]], limits: dict[str, Any]) -> None:
        self.base = path
        self.topics = topics
        self.max_bytes = limits.get("max_bytes") or 0
        self.max_seconds = limits.get("max_seconds") or 0
        self.max_files = limits.get("max_files") or 0
        self.compression = limits.get("compression") or "lz4"
        self.chunk_bytes = limits.get("chunk_bytes") or CHUNK_BYTES
        self.file: _File | None = None
        self.index = 0
        self.written = 0

    def on_start(self) -> None:
        existing = _rotations(self.base)
        if existing:  # a restart (the root refuses a first start on an existing file): never overwrite
            self.index = existing[-1][0] + 1
        self._open()
        for name, wire, keep, queue in self.topics:
            cls = message_class(wire) if wire else None
            self.context.subscribe(name, partial(self._write, name, cls),
                                   keep=keep, queue_size=max(int(queue), 100 if keep == "all" else 30),
                                   msg_type=cls)  # another type on the topic is counted as bad, not written
        log.info("recording %d topics to %s", len(self.topics), self.file.path if self.file else self.base)

    def _open(self) -> None:
        self.file = _File(rotation_path(self.base, self.index), self.compression, self.chunk_bytes)
        if self.max_files:
            for old in rotation_files(self.base)[:-self.max_files]:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(old)

    def _write(self, topic: str, cls: type | None, msg: Any) -> None:
        if self.file is None:  # rotated: the next file starts with its first message (none is left empty)
            self._open()
        f = self.file
        assert f is not None
        now = time.time_ns()
        stamp = getattr(msg, "stamp", 0.0)
        data = kind_of(cls).encode(msg)
        f.writer.add_message(f.channel(topic, cls), log_time=now, data=data,
                             publish_time=int(stamp * 1e9) if stamp else now, sequence=f.messages)
        f.messages += 1
        self.written += 1
        if (self.max_bytes and f.stream.tell() >= self.max_bytes) or (
                self.max_seconds and time.monotonic() - f.opened >= self.max_seconds):
            f.close()
            log.info("rotated %s (%d messages)", f.path, f.messages)
            self.index += 1
            self.file = None

    def on_receive(self, message: Any) -> Any:
        """``"stats"`` -> the file being written and how many messages so far."""
        if message == "stats":
            return {"path": rotation_path(self.base, self.index), "messages": self.written}
        return None

    def on_stop(self) -> None:
        if self.file is not None:
            self.file.close()
            log.info("closed %s (%d messages in all)", self.file.path, self.written)
            self.file = None
