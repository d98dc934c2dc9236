"""Exceptions raised by the actor runtime.

Every error names the problem and, where there is one, the fix::

    >>> raise ActorNotFound("camera", known=["llm", "tts"])
    Traceback (most recent call last):
    actors.errors.ActorNotFound: no actor named 'camera' in this run (known: llm, tts); ...
"""

from __future__ import annotations

import builtins
import reprlib
from collections.abc import Iterable
from typing import Any

from pykka import Timeout

__all__ = [
    "ActorCrashed",
    "ActorError",
    "ActorNotFound",
    "CodecError",
    "CorruptFrame",
    "MessageTooLarge",
    "RemoteError",
    "StaleFrame",
    "Timeout",
    "UnknownMessage",
    "UnregisteredType",
    "quote",
]


class _Quoter(reprlib.Repr):
    """reprlib's bounded repr, also for bytes and for objects whose repr would be built whole first."""

    def repr_bytes(self, x: bytes, level: int) -> str:
        return builtins.repr(x[: self.maxstring]) + ("..." if len(x) > self.maxstring else "")

    repr_bytearray = repr_bytes

    def repr_instance(self, x: Any, level: int) -> str:
        fields = getattr(type(x), "__attrs_attrs__", None)  # a message: its fields, each bounded
        if fields is None or level <= 0:
            return super().repr_instance(x, level)
        inner = ", ".join(f"{f.name}={self.repr1(getattr(x, f.name, None), level - 1)}" for f in fields[:8])
        return f"{type(x).__name__}({inner}{', ...' if len(fields) > 8 else ''})"


_quoter = _Quoter()
_quoter.maxstring = _quoter.maxother = 80
_quoter.maxlist = _quoter.maxdict = _quoter.maxtuple = _quoter.maxset = 8


def quote(value: Any, limit: int = 200) -> str:
    """``repr(value)`` in at most about ``limit`` characters, for error messages that quote a request.

    A 10 MB request quoted whole in its error went back to its sender whole (and doubled
    the receiver's memory while it did).

    >>> quote("x" * 10_000_000)[:12], len(quote("x" * 10_000_000)) <= 204
    ("'xxxxxxxxxxx", True)
    """
    text = _quoter.repr(value)
    return text if len(text) <= limit else f"{text[:limit]}..."


class ActorError(Exception):
    """Base class of every error the runtime raises on purpose."""


class ActorNotFound(ActorError, LookupError):
    """A ref was asked for a name that no actor in this run has."""

    def __init__(self, name: str, known: Iterable[str] = ()) -> None:
        known = sorted(known)
        listing = ", ".join(known) if known else "none"
        super().__init__(
            f"no actor named {name!r} in this run (known: {listing}); "
            "check the spelling or spawn it first"
        )
        self.name = name


class ActorCrashed(ActorError):
    """The actor process died (or restarted) before it answered an ask."""

    def __init__(self, name: str, detail: str = "") -> None:
        msg = f"actor {name!r} died before answering"
        super().__init__(f"{msg}: {detail}" if detail else msg)
        self.name = name


class RemoteError(ActorError):
    """A handler raised; carries the remote exception type and traceback text."""

    def __init__(self, actor: str, exc_type: str, message: str, traceback: str) -> None:
        super().__init__(
            f"actor {actor!r} raised {exc_type}: {message}\n--- remote traceback ---\n{traceback}"
        )
        self.actor = actor
        self.exc_type = exc_type
        self.remote_message = message
        self.remote_traceback = traceback


class CodecError(ActorError, ValueError):
    """A value could not be encoded or decoded."""


class UnregisteredType(CodecError, TypeError):
    """An object of a class that is neither msgpack-native nor a registered message."""


class CorruptFrame(CodecError):
    """Bytes on a socket that are not a frame of ours (foreign, truncated or corrupt)."""


class MessageTooLarge(CodecError):
    """A message is larger than the configured limit."""

    def __init__(self, size: int, limit: int, what: str = "message") -> None:
        super().__init__(
            f"{what} of {size} bytes exceeds the limit of {limit} bytes; "
            "send large data as numpy arrays (they travel through shared memory) "
            "or raise max_message_bytes"
        )
        self.size = size
        self.limit = limit


class UnknownMessage(ActorError, ValueError):
    """A message the actor does not understand: an ask gets this error back; a tell is dead-lettered and
    logged (a restart would not make it understood), never a crash. The message is quoted briefly.

    >>> str(UnknownMessage("component 'llm'", {"cmd": "x" * 500}, "send a Call"))
    "component 'llm': unknown request {'cmd': 'xxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx...xxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx'}; send a Call"
    """

    def __init__(self, who: str, message: Any, expected: str) -> None:
        super().__init__(f"{who}: unknown request {quote(message)}; {expected}")


class StaleFrame(ActorError):
    """A shared-memory frame was reused or released before this receiver mapped it."""
