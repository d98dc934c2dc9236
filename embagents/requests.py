"""Requests to a component's actor and to the root's supervisor, as registered message classes.

The events actor builds them from an event's or a fallback's action; the
component actor (:class:`Call`, :class:`Reconfigure`, :class:`ChangeModelClient`,
:class:`HealthQuery`) and the root's supervisor (:class:`SupervisorRequest`,
published on :data:`SUPERVISOR_REQUESTS`) carry them out. Anyone may send
them (tests, tools): ``ref.ask(Call("history"))``. What components send the
events actor to act for them (:class:`ToolCall`, an LLM's tool call;
:class:`RouteFired`, a router's fired route) lives here too, so that
components may send them without importing the runtime.

Example::

    >>> from actors.codec import Codec
    >>> frame, _ = Codec().encode(Call("greet", ("ada",)), shm=False)
    >>> Codec().decode(frame)
    Call(method='greet', args=['ada'], kwargs={}, deadline=None)
    >>> SupervisorRequest("reboot", "camera")
    Traceback (most recent call last):
    ...
    ValueError: unknown supervisor request 'reboot' for 'camera'; one of: start, stop, restart, give_up
    >>> Codec().decode(Codec().encode(ToolCall("memory", "locate", {"what": "cup"}), shm=False)[0]).method
    'locate'
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import attrs

from actors.codec import message

__all__ = [
    "EVENTS_ACTOR",
    "SUPERVISOR_REQUESTS",
    "SUPERVISOR_REQUEST_KINDS",
    "Call",
    "ChangeModelClient",
    "HealthQuery",
    "Reconfigure",
    "SupervisorRequest",
    "ToolCall",
    "RouteFired",
]

#: The topic that carries :class:`SupervisorRequest` messages to the root's supervisor.
SUPERVISOR_REQUESTS = "_supervisor_requests"
SUPERVISOR_REQUEST_KINDS = ("start", "stop", "restart", "give_up")
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


def _as_list(value: Iterable[Any]) -> list[Any]:
    # Named (not ``converter=list``): mypy's attrs plugin then types ``args`` as any iterable, not ``Iterable[_T]``.
    return list(value)


@message("embagents/Call")
@attrs.define
class Call:
    """Call ``component.<method>(*args, **kwargs)``; an ask gets its return value.

    ``deadline`` (``time.monotonic()``, the clock every process of the machine
    shares): when the caller stops waiting. A call still in the mailbox then
    (behind a slow one) is not run: its caller was told it failed.
    """

    method: str
    args: list[Any] = attrs.field(factory=list, converter=_as_list)
    kwargs: dict[str, Any] = attrs.field(factory=dict, converter=dict)
    deadline: float | None = None


@message("embagents/Reconfigure")
@attrs.define
class Reconfigure:
    """Apply config ``overrides`` to the component (``Component.reconfigure``)."""

    overrides: dict[str, Any] = attrs.field(converter=dict)


@message("embagents/ChangeModelClient")
@attrs.define
class ChangeModelClient:
    """Swap a model component's active client (by name); an ask gets the previous name."""

    client: Any


@message("embagents/HealthQuery")
@attrs.define
class HealthQuery:
    """Ask a component how it is: ``{"status": int, "text": str}``."""


def _check_kind(req: SupervisorRequest, _attr: Any, kind: str) -> None:
    if kind not in SUPERVISOR_REQUEST_KINDS:
        raise ValueError(
            f"unknown supervisor request {kind!r} for {req.component!r}; one of: {', '.join(SUPERVISOR_REQUEST_KINDS)}"
        )


@message("embagents/SupervisorRequest")
@attrs.define
class SupervisorRequest:
    """Start, stop, restart or give up on component ``component`` (``because`` says why, for the log)."""

    kind: str = attrs.field(validator=_check_kind)
    component: str
    because: str = ""

