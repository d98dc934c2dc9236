"""What components send the events actor to act for them: an LLM's tool call, a router's fired route.

Kept apart from :mod:`embagents.runtime` (which hosts the events actor) so
that components may send them without importing the runtime.

Example::

    >>> from actors.codec import Codec
    >>> Codec().decode(Codec().encode(ToolCall("memory", "locate", {"what": "cup"}), shm=False)[0]).method
    'locate'
"""

from __future__ import annotations

from typing import Any

import attrs

from actors.codec import message

__all__ = ["EVENTS_ACTOR", "RouteFired", "ToolCall"]

#: The name of the events actor (it runs events, fallbacks, LLM tool calls and route actions).
EVENTS_ACTOR = "_events"


@message("embagents/ToolCall")
@attrs.define
class ToolCall:
    """An LLM's tool call for the events actor: run ``component.<method>(**kwargs)``, answer its result.

    Bad arguments (names or count the method does not take) are refused with a
    ``TypeError`` naming the method's parameters, before the component is asked.
    """

    component: str
    method: str
    kwargs: dict[str, Any] = attrs.field(factory=dict, converter=dict)


@message("embagents/RouteFired")
@attrs.define
class RouteFired:
    """A router sent a text down route ``route`` (an output topic name): the events actor runs that route's actions."""

    component: str
    route: str
    text: str = ""
