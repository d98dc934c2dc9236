"""``embagents publish TOPIC TEXT``: a message on a topic of a running system, from another terminal.

The root of ``embagents supervise`` serves a ``publish`` control command
(:func:`publish_command`): it builds the topic's message type from the
fields it is sent and publishes it from the root's own runtime, like any
publisher of the run. :func:`publish` is the client side (through
:class:`embagents.live.LiveRun`, which scripts use directly): a positional text
becomes the ``data`` field (``String``, ``StreamingString``); other fields
come as JSON.

Example (a chat system serving with ``EMBAGENTS_KEEP_RUNNING=1``)::

    $ embagents publish text_in "What is the capital of Italy?"
    published String on text_in (run 1a2b3c, system chat)
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import attrs

from actors.topics import Publisher
from embagents.live import connect
from embagents.tools.plain import build_message

if TYPE_CHECKING:  # for the annotation only: embagents.system imports most of the package
    from embagents.system import System

__all__ = ["publish", "publish_command"]


def _message(topic: Any, fields: dict[str, Any]) -> Any:
    """``topic.msg_type(**fields)``, or ValueError naming the fields the type has."""

    cls = topic.msg_type
    if not attrs.has(cls):
        raise ValueError(f"topic {topic.name!r} carries {topic.type_name}, which has no fields to fill in")
    try:
        return build_message(cls, fields)
    except ValueError as exc:
        raise ValueError(f"topic {topic.name!r}: {exc}") from None


def publish_command(asys: Any, system: System) -> Callable[[dict[str, Any]], dict[str, Any]]:
    """The root's handler of ``{"cmd": "publish", "topic": NAME, "fields": {...}}`` for ``system``."""

    publishers: dict[str, Any] = {}  # one per topic, made on the root's IO thread when first used

    def handle(req: dict[str, Any]) -> dict[str, Any]:
        name, fields = req.get("topic"), req.get("fields") or {}
        topics = system.topics
        topic = topics.get(name) if isinstance(name, str) else None
        if topic is None or not isinstance(name, str):
            return {"ok": False, "error": f"system {system.name!r} has no topic {name!r}; "
                    f"its topics: {', '.join(sorted(topics)) or 'none'}"}
        if not isinstance(fields, dict):
            return {"ok": False, "error": f"fields must be a JSON object, got {fields!r}"}
        try:
            msg = _message(topic, fields)
        except ValueError as exc:
            return {"ok": False, "error": str(exc)}

        def send() -> None:
            if name not in publishers:
                publishers[name] = Publisher(asys.rt, name, topic.msg_type)
            publishers[name].publish(msg)

        asys.rt.on_client(send)
        return {"ok": True, "topic": name, "type": topic.type_name}

    return handle


def publish(topic: str, text: str | None = None, fields: str | None = None, *, run: str | None = None,
            timeout: float = 5.0) -> dict[str, Any]:
    """Publish on ``topic`` of the live run ``run`` (default: the only one); returns the root's answer.

    ``text`` is the ``data`` field; ``fields`` a JSON object of fields. Raises
    ``supervisor.client.ControlError`` (no run, unknown topic, bad fields) or ``ValueError`` (bad JSON).
    """

    values: dict[str, Any] = {}
    if fields:
        try:
            values = json.loads(fields)
        except ValueError as exc:
            raise ValueError(f"--fields is not JSON ({exc}): pass an object such as '{{\"data\": \"hi\"}}'") from None
        if not isinstance(values, dict):
            raise ValueError(f"--fields must be a JSON object such as '{{\"data\": \"hi\"}}', got {fields!r}")
    with connect(run, timeout=timeout) as live:
        reply = live.publish(topic, text, **values)  # text, if given, is the data field
        return {**reply, "run_id": live.run_id, "system": live.system}
