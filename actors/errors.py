"""Exceptions raised by the actor runtime.

Every error names the problem and, where there is one, the fix::

    >>> raise ActorNotFound("camera", known=["llm", "tts"])
    Traceback (most recent call last):
    actors.errors.ActorNotFound: no actor named 'camera' in this run (known: llm, tts); ...
"""

from __future__ import annotations

from collections.abc import Iterable

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
    "UnregisteredType",
]


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


class StaleFrame(ActorError):
    """A shared-memory frame was reused or released before this receiver mapped it."""
