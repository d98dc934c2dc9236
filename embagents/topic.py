"""Topics: named, typed streams between components.

A topic name is ROS-like (letters, digits and ``_`` in tokens joined by single
``/``; a leading ``/`` is dropped, as internal names are relative); its message type is a registered message class, given as the class or
its name. ``queue_size`` and ``keep`` are the subscribers' queue policy:
``keep="latest"`` drops the oldest queued message when the queue is full
(sensor streams may drop old frames; ROS's keep-last), ``keep="all"`` never
replaces a queued message: past ``queue_size`` the publisher is held back
(ZeroMQ high-water mark) instead.

Example::

    >>> from embagents.msgs import Image
    >>> Topic("camera/image", "Image").msg_type is Image
    True
    >>> Topic("camera/image", Image, queue_size=1).keep
    'latest'
    >>> Topic("9lives", "String")
    Traceback (most recent call last):
    embagents.topic.TopicError: invalid topic name '9lives': ...
"""

from __future__ import annotations

import re
from typing import Any, Literal

import attrs

from actors.codec import message_class, message_name
from actors.errors import UnregisteredType
from embagents.msgs import MESSAGE_TYPES

__all__ = [
    "KEEP_POLICIES",
    "FixedInput",
    "Topic",
    "TopicError",
    "add_message_type",
    "known_message_types",
    "resolve_msg_type",
]

KEEP_POLICIES = ("latest", "all")

_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
_NAME = re.compile(rf"^{_TOKEN}(/{_TOKEN})*$")  # after the leading "/" is dropped

# Message classes registered outside embagents.msgs (Health, user types) that
# may be named by their class name too.
_EXTRA_TYPES: dict[str, type] = {}


class TopicError(ValueError):
    """A topic declaration is invalid (bad name, unknown type, bad queue policy)."""


def known_message_types() -> dict[str, type]:
    """Message classes a topic may carry when named by string, by class name.

    >>> "String" in known_message_types()
    True
    """
    return {**MESSAGE_TYPES, **_EXTRA_TYPES}


def add_message_type(cls: type) -> type:
    """Make a registered message class nameable by its class name in ``Topic(name, "Cls")``."""
    message_name(cls)  # raises if not registered with the codec
    _EXTRA_TYPES[cls.__name__] = cls
    return cls


def _known_text() -> str:
    return ", ".join(sorted(known_message_types()))


def resolve_msg_type(msg_type: type | str, *, what: str = "topic") -> type:
    """The message class for a class or a name (class name or wire name).

    >>> resolve_msg_type("embagents/String").__name__
    'String'
    """
    if isinstance(msg_type, str):
        cls = known_message_types().get(msg_type)
        if cls is not None:
            return cls
        try:  # a wire name such as "embagents/Image" or a user's "demo/Point"
            return message_class(msg_type)
        except UnregisteredType:
            raise TopicError(
                f"{what}: unknown message type {msg_type!r}; known types: {_known_text()}"
            ) from None
    if isinstance(msg_type, type):
        try:
            message_name(msg_type)
        except UnregisteredType:
            raise TopicError(
                f"{what}: {msg_type.__qualname__} is not a registered message class "
                f"(decorate it with @actors.message(...)); known types: {_known_text()}"
            ) from None
        return msg_type
    raise TopicError(
        f"{what}: msg_type must be a message class or its name, got {msg_type!r}; "
        f"known types: {_known_text()}"
    )


def _strip_slash(name: object) -> object:
    # "/camera" and "camera" are one internal topic (as RosInput.topic strips it too).
    return name[1:] if isinstance(name, str) and name.startswith("/") else name


def _check_name(_inst: object, _attr: attrs.Attribute[str], name: object) -> None:
    if not isinstance(name, str) or not _NAME.match(name):
        raise TopicError(
            f"invalid topic name {name!r}: use tokens of letters, digits and '_' (not starting "
            "with a digit) joined by single '/', e.g. 'camera/image_raw'"
        )


def _check_queue_size(inst: Topic, _attr: object, value: object) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise TopicError(f"topic {inst.name!r}: queue_size must be an int >= 1, got {value!r}")


def _check_keep(inst: Topic, _attr: object, value: object) -> None:
    if value not in KEEP_POLICIES:
        raise TopicError(f"topic {inst.name!r}: keep must be 'latest' or 'all', got {value!r}")


@attrs.frozen
class Topic:
    """A named stream of messages of one type (see the module docstring)."""

    name: str = attrs.field(converter=_strip_slash, validator=_check_name)
    msg_type: type = attrs.field()
    queue_size: int = attrs.field(default=10, validator=_check_queue_size)
    keep: Literal["latest", "all"] = attrs.field(default="latest", validator=_check_keep)

    def __attrs_post_init__(self) -> None:
        # A converter cannot name the topic in its error, so resolve here.
        object.__setattr__(self, "msg_type", resolve_msg_type(self.msg_type, what=f"topic {self.name!r}"))

    @property
    def type_name(self) -> str:
        """The message class name, e.g. ``"Image"``."""
        return self.msg_type.__name__

    def __str__(self) -> str:
        return f"{self.name} ({self.type_name})"


def _fixed_message(msg_type: type, value: Any, name: str) -> Any:
    """The message a FixedInput gives every step: ``value`` itself, or a str wrapped in a String-like type."""
    if isinstance(value, msg_type):
        return value
    if isinstance(value, str) and "data" in attrs.fields_dict(msg_type):
        return msg_type(data=value)
    raise TopicError(f"FixedInput {name!r}: fixed must be a {msg_type.__name__} (or, for a text type, a str), "
                     f"got {value!r}")


@attrs.frozen
class FixedInput(Topic):
    """A constant input: every step of the component gets ``fixed`` on it, and nothing subscribes.

    For a component triggered by an event or a rate that asks the same thing each time
    (``FixedInput("prompt", String, fixed="What do you see?")``); ``fixed`` is a message of
    ``msg_type`` or, for a text type, a str. It is never published and needs no publisher.

    >>> from embagents.msgs import String
    >>> FixedInput("prompt", "String", fixed="What do you see?").message
    String(data='What do you see?')
    """

    fixed: Any = attrs.field(default=None, kw_only=True, eq=False)

    def __attrs_post_init__(self) -> None:
        super().__attrs_post_init__()
        object.__setattr__(self, "fixed", _fixed_message(self.msg_type, self.fixed, self.name))

    @property
    def message(self) -> Any:
        """The message each step gets."""
        return self.fixed
