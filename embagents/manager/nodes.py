"""Nodes on topics: the manager's window on the system's (and so ROS's) topics.

A :class:`Node` subscribes to topics and caches the latest message of each
for handlers to read, and publishes results on its declared output topics,
checked by type. It is bound when the manager runs as an actor of a System
(``embagents supervise``): subscription callbacks then run on the loop's own
thread, between ticks, so a handler never sees a half-written cache. ROS
topics reach it through the ROS bridge actor: no rclpy in this process.

Example::

    >>> from embagents.msgs import String
    >>> from embagents.topic import Topic
    >>> cmd, status = Topic("cmd", String), Topic("status", String)
    >>> node = Node("io", subscribe=[cmd], publish=[status])
    >>> sent = []
    >>> node.bind(lambda topic, msg: sent.append((topic, msg.data)))
    >>> node.deliver("cmd", String(data="go"))
    >>> node.latest(cmd).data, node.received("cmd")
    ('go', True)
    >>> node.publish(status, String(data="ok")); sent
    [('status', 'ok')]
    >>> node.publish(status, 3.0)
    Traceback (most recent call last):
    TypeError: node 'io': topic 'status' expects String, got float; publish a String there
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from embagents.topic import Topic

__all__ = ["Node", "NodeNotBound"]

Publish = Callable[[str, Any], None]


class NodeNotBound(RuntimeError):
    """A node was used outside a running System: it has no topics to publish on."""


def _topic_name(topic: Topic | str) -> str:
    name = topic.name if isinstance(topic, Topic) else str(topic)
    return name[1:] if name.startswith("/") else name


class Node:
    """Subscribes to ``subscribe`` topics (latest message cached), publishes on ``publish``.

    Override :meth:`on_message` to react to each message as it arrives (it
    runs on the loop's thread, between ticks), e.g. to ``post`` an event to
    a state machine.
    """

    def __init__(
        self, name: str, *, subscribe: Sequence[Topic] = (), publish: Sequence[Topic] = ()
    ) -> None:
        for t in (*subscribe, *publish):
            if not isinstance(t, Topic):
                raise TypeError(f"node {name!r}: topics must be Topic(name, msg_type) declarations, got {t!r}")
        self.name = name
        self.subscriptions: tuple[Topic, ...] = tuple(subscribe)
        self.outputs: dict[str, Topic] = {t.name: t for t in publish}
        self._latest: dict[str, Any] = {}
        self._counts: dict[str, int] = {}
        self._publish: Publish | None = None

    # -- wiring (done by the manager's actor) ----------------------------------
    def bind(self, publish: Publish) -> None:
        """Give the node its way to publish (the actor's topic publisher)."""
        self._publish = publish

    def deliver(self, topic: str, msg: Any) -> None:
        """A message arrived on ``topic``: cache it, count it, call :meth:`on_message`."""
        self._latest[topic] = msg
        self._counts[topic] = self._counts.get(topic, 0) + 1
        self.on_message(topic, msg)

    # -- what handlers use ----------------------------------------------------
    def on_message(self, topic: str, msg: Any) -> None:
        """Hook: called for every message, after it is cached."""

    def latest(self, topic: Topic | str, default: Any = None) -> Any:
        """The last message received on ``topic`` (``default`` before the first)."""
        name = _topic_name(topic)
        if name not in self._latest and name not in {t.name for t in self.subscriptions}:
            known = ", ".join(t.name for t in self.subscriptions) or "none"
            raise KeyError(f"node {self.name!r} does not subscribe to {name!r}; it subscribes to: {known}")
        return self._latest.get(name, default)

    def received(self, topic: Topic | str) -> bool:
        """True once a message arrived on ``topic``."""
        return _topic_name(topic) in self._latest

    def count(self, topic: Topic | str) -> int:
        """Messages received on ``topic`` so far."""
        return self._counts.get(_topic_name(topic), 0)

    def publish(self, topic: Topic | str, msg: Any) -> None:
        """Publish ``msg`` on one of this node's output topics (checked by type)."""
        name = _topic_name(topic)
        out = self.outputs.get(name)
        if out is None:
            known = ", ".join(self.outputs) or "none"
            raise KeyError(
                f"node {self.name!r} does not publish on {name!r}; declare it in Node(publish=[...]) "
                f"(it publishes on: {known})"
            )
        if not isinstance(msg, out.msg_type):
            raise TypeError(
                f"node {self.name!r}: topic {name!r} expects {out.type_name}, got {type(msg).__name__}; "
                f"publish a {out.type_name} there"
            )
        if self._publish is None:
            raise NodeNotBound(
                f"node {self.name!r} is not running in a System: declare its manager in "
                "System(managers=[...]) and start it with `embagents supervise system.py`"
            )
        self._publish(name, msg)

    def __repr__(self) -> str:
        subs = ", ".join(t.name for t in self.subscriptions)
        pubs = ", ".join(self.outputs)
        return f"<Node {self.name!r} in: [{subs}] out: [{pubs}]>"
