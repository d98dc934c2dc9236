"""The shared state that the manager's handlers read and write each tick.

Values are reachable as attributes and as keys. Every write takes one lock,
so callbacks on other threads (topic subscriptions, attached agents) can
feed the loop safely; hold :attr:`State.lock` for read-modify-write.

Example::

    >>> state = State(mode="idle")
    >>> state.update(speed=0.2, heading=90)
    >>> state.mode, state["speed"]
    ('idle', 0.2)
    >>> with state.lock:
    ...     state.heading += 10
    >>> state.receive("camera", "frame-0")
    >>> state.received["camera"], sorted(state.snapshot())
    (True, ['camera', 'heading', 'mode', 'speed'])
"""

from __future__ import annotations

import threading
from collections.abc import Iterator, Mapping, MutableMapping
from types import MappingProxyType
from typing import Any

__all__ = ["State"]


class State(MutableMapping[str, Any]):
    """Thread-safe key/value state with attribute access.

    Names of methods (``update``, ``get``, ``keys``, ``lock``, ``received``...)
    are reserved as attributes; such values are still reachable as keys.
    """

    def __init__(self, values: Mapping[str, Any] | None = None, /, **kwargs: Any) -> None:
        # Internals bypass __setattr__, which routes everything else to the data.
        object.__setattr__(self, "_lock", threading.RLock())
        object.__setattr__(self, "_data", {})
        object.__setattr__(self, "_received", {})
        object.__setattr__(self, "_version", 0)
        self.update(values or {}, **kwargs)

    @property
    def lock(self) -> threading.RLock:
        """Re-entrant lock guarding every read and write; hold it for compound updates."""
        return self._lock

    @property
    def received(self) -> Mapping[str, bool]:
        """Read-only view: ``received[key]`` is True once :meth:`receive` stored ``key``."""
        return MappingProxyType(self._received)

    @property
    def revision(self) -> int:
        """Counts writes of values (not :meth:`receive`), so a snapshot is taken only after a change."""
        return self._version

    def _bump(self) -> None:
        object.__setattr__(self, "_version", self._version + 1)

    def mark_received(self, key: str) -> None:
        """Mark ``key`` received without storing anything (a topic's first message, say)."""
        with self.lock:
            self._received[key] = True

    def kept(self) -> dict[str, Any]:
        """The values handlers wrote, without received messages (they are stale after a restart)."""
        with self.lock:
            received = self._received
            return {k: v for k, v in self._data.items() if k not in received}

    def receive(self, key: str, message: Any) -> None:
        """Store an incoming ``message`` under ``key`` and mark it received."""
        with self.lock:
            self._data[key] = message
            self._received[key] = True

    def update(self, values: Any = (), /, **kwargs: Any) -> None:
        """Set several values at once, atomically (readers never see half of them)."""
        new = dict(values, **kwargs)
        with self.lock:
            self._data.update(new)
            self._bump()

    def snapshot(self) -> dict[str, Any]:
        """A plain-dict copy of the values (shallow), consistent at one instant."""
        with self.lock:
            return dict(self._data)

    def get(self, key: str, default: Any = None) -> Any:
        with self.lock:
            return self._data.get(key, default)

    def setdefault(self, key: str, default: Any = None) -> Any:
        with self.lock:
            if key not in self._data:
                self._bump()
            return self._data.setdefault(key, default)

    # Mapping protocol ----------------------------------------------------

    def __getitem__(self, key: str) -> Any:
        with self.lock:
            return self._data[key]

    def __setitem__(self, key: str, value: Any) -> None:
        with self.lock:
            self._data[key] = value
            self._bump()

    def __delitem__(self, key: str) -> None:
        with self.lock:
            del self._data[key]
            self._received.pop(key, None)
            self._bump()

    def __iter__(self) -> Iterator[str]:
        # Iterate a copy: another thread may add keys meanwhile.
        return iter(self.snapshot())

    def __len__(self) -> int:
        return len(self._data)

    # Attribute access ----------------------------------------------------

    def __getattr__(self, name: str) -> Any:
        # Only called when normal lookup fails. Private names never come from
        # the data, so copy/pickle probes during construction cannot recurse.
        if name.startswith("_"):
            raise AttributeError(name)
        try:
            return self[name]
        except KeyError:
            known = ", ".join(sorted(self._data)) or "none"
            raise AttributeError(f"state has no value {name!r} (keys: {known})") from None

    def __setattr__(self, name: str, value: Any) -> None:
        if name.startswith("_") or hasattr(type(self), name):
            raise AttributeError(
                f"{name!r} is reserved on State; use state[{name!r}] = ... instead"
            )
        self[name] = value

    def __delattr__(self, name: str) -> None:
        try:
            del self[name]
        except KeyError:
            raise AttributeError(f"state has no value {name!r}") from None

    def __repr__(self) -> str:
        items = ", ".join(f"{k}={v!r}" for k, v in self.snapshot().items())
        return f"State({items})"
