"""Snapshots: an actor that defines ``snapshot()`` and ``restore(state)`` keeps what it knew.

In the actor's process, after a handled message (tell or ask; not control
messages) the runtime calls ``snapshot()`` and writes its value, msgpack
encoded (numpy arrays and registered message classes allowed), atomically
(write to a temporary file, then rename) to ``{run_dir}/{name}.snap``. With
``snapshot_interval=0`` (the default) that happens after every message,
*before* the message is acknowledged, so every acknowledged message's
effect is in the snapshot; with an interval of s seconds at most one
snapshot is written per s seconds (the last change is written when the
interval has passed, and on a clean stop), and a crash may lose up to s
seconds of effects of messages that were already acknowledged.

A new incarnation calls ``restore(state)`` with the last snapshot before
``on_start``. An undecodable snapshot is logged and set aside (renamed to
``.snap.bad``); the actor then starts fresh. ``delete_child`` removes it.

Example::

    >>> class Chat(Actor):                                 # doctest: +SKIP
    ...     def on_start(self): self.history = getattr(self, "history", [])
    ...     def on_receive(self, msg): self.history.append(msg)
    ...     def snapshot(self): return {"history": self.history}
    ...     def restore(self, state): self.history = state["history"]
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections.abc import Mapping
from typing import Any

from actors import ActorHost, Codec, CodecError, HostExtension, wire

__all__ = ["Snapshots", "keeps_snapshots", "read"]

log = logging.getLogger("supervisor.snapshot")

_codec = Codec()


def read(path: str) -> Any:
    """Decode the snapshot at ``path`` (raises FileNotFoundError or CodecError)."""
    with open(path, "rb") as f:
        return _codec.decode(f.read())


class Snapshots(HostExtension):
    """Restores an actor before ``on_start`` and writes its snapshots, at most one per ``interval`` s.

    A host extension (config: ``{"interval": seconds}``); the supervisor adds
    it to actors whose class defines ``snapshot()`` and ``restore(state)``.
    """

    name = "snapshots"

    def __init__(self, host: ActorHost, config: Mapping[str, Any]) -> None:
        super().__init__(host, config)
        actor = host.actor
        if not keeps_snapshots(type(actor)):
            raise TypeError(f"{type(actor).__qualname__} needs snapshot() and restore(state) methods to keep snapshots")
        self.actor: Any = actor
        self.interval = float(config.get("interval") or 0.0)
        self.path = os.path.join(host.rt.run_dir, f"{host.name}.snap")
        self.dirty = False
        self.last = 0.0
        self.timer: int | None = None
        self.written = 0

    def before_start(self) -> None:
        self.restore()

    def after_message(self, kind: int, ok: bool) -> None:
        # An ask that raised may have changed the state; a tell that raised crashes the
        # actor and is delivered again, so its half-done effects must not persist.
        if kind == wire.ASK or (ok and kind == wire.TELL):
            self.changed()

    def state_changed(self) -> None:
        self.changed()

    def after_stop(self) -> None:
        if self.dirty:
            self.write()

    def restore(self) -> bool:
        try:
            state = read(self.path)
        except FileNotFoundError:
            return False
        except CodecError as exc:
            log.error("[%s] snapshot %s is unreadable (%s); starting fresh", self.host.name, self.path, exc)
            with contextlib.suppress(OSError):
                os.replace(self.path, self.path + ".bad")
            return False
        self.actor.restore(state)
        log.info("[%s] restored from its snapshot", self.host.name)
        return True

    def changed(self) -> None:
        self.dirty = True
        now = time.monotonic()
        wait = self.interval - (now - self.last)
        if wait <= 0:
            self.write()
        elif self.timer is None:
            self.timer = self.host.loop.call_later(wait, self._due)

    def _due(self) -> None:
        self.timer = None
        if self.dirty:
            self.write()

    def write(self) -> None:
        data, _ = _codec.encode(self.actor.snapshot(), shm=False)
        tmp = f"{self.path}.tmp"
        with open(tmp, "wb") as f:
            f.write(data)
        os.replace(tmp, self.path)  # atomic: a reader sees the old or the new snapshot, never half
        self.dirty = False
        self.last = time.monotonic()
        self.written += 1


def keeps_snapshots(cls: type) -> bool:
    """True if actor class ``cls`` defines ``snapshot()`` and ``restore(state)``."""
    return callable(getattr(cls, "snapshot", None)) and callable(getattr(cls, "restore", None))
