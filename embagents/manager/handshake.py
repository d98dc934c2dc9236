"""Handshake rules: conditions on the shared state that must hold before tick 1.

The manager checks every rule at the loop rate and starts ticking once all
hold; past the timeout it raises :class:`HandshakeTimeout`, naming the rules
still unmet so the log says what never arrived.

Example::

    >>> from embagents.manager.state import State
    >>> rule = HandshakeRule.message_received("camera", name="first_camera_frame",
    ...                                       description="a frame on /camera/image")
    >>> state = State()
    >>> rule.check(state)
    False
    >>> state.receive("camera", b"jpeg")
    >>> rule.check(state)
    True
    >>> str(HandshakeTimeout([(rule, None)], timeout=5.0))
    'handshake not complete after 5 s; waiting for: first_camera_frame (a frame on /camera/image)'
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from typing import Any

import attrs

from embagents.manager.state import State

__all__ = ["HandshakeProgress", "HandshakeRule", "HandshakeTimeout", "wait_for_handshake"]


@attrs.frozen
class HandshakeRule:
    """A named condition over the shared state, described for humans."""

    name: str
    predicate: Callable[[State], bool]
    description: str = ""
    #: The topic a :meth:`first_message` rule waits for (a node of the manager must subscribe to it).
    topic: str | None = None

    @classmethod
    def message_received(
        cls, key: str, *, name: str | None = None, description: str | None = None
    ) -> HandshakeRule:
        """Holds once a message was stored under ``key`` (see ``Manager.on_message``)."""
        return cls(
            name=name or f"{key}_received",
            predicate=lambda state: bool(state.received.get(key)),
            description=description or f"a message for state[{key!r}]",
        )

    @classmethod
    def has_value(
        cls, key: str, *, name: str | None = None, description: str | None = None
    ) -> HandshakeRule:
        """Holds once ``state[key]`` exists and is not None (set by anyone)."""
        return cls(
            name=name or f"{key}_set",
            predicate=lambda state: state.get(key) is not None,
            description=description or f"a value for state[{key!r}]",
        )

    @classmethod
    def first_message(
        cls, topic: Any, *, name: str | None = None, description: str | None = None
    ) -> HandshakeRule:
        """Holds once a message arrived on ``topic`` (a Topic or its name) for one of the manager's nodes."""
        key = getattr(topic, "name", topic)
        key = key[1:] if isinstance(key, str) and key.startswith("/") else key
        return cls(
            name=name or f"first_message_on_{str(key).replace('/', '_')}",
            predicate=lambda state: bool(state.received.get(key)),
            description=description or f"a first message on {key}",
            topic=str(key),
        )

    def check(self, state: State) -> bool:
        """Evaluate the predicate; an exception counts as "not yet"."""
        return self.evaluate(state)[0]

    def evaluate(self, state: State) -> tuple[bool, BaseException | None]:
        """Like :meth:`check`, also returning the exception the predicate raised."""
        # Predicates such as `lambda s: s.battery > 0.2` raise until the first
        # reading arrives; that means "unmet", and the error goes in the report.
        try:
            return bool(self.predicate(state)), None
        except Exception as exc:
            return False, exc

    def explain(self, error: BaseException | None = None) -> str:
        """``name (description)``, plus the predicate's last error if any."""
        details = [d for d in (self.description, _error_text(error)) if d]
        return f"{self.name} ({'; '.join(details)})" if details else self.name


class HandshakeTimeout(TimeoutError):
    """The handshake rules did not all hold within the timeout."""

    def __init__(
        self, unmet: Sequence[tuple[HandshakeRule, BaseException | None]], timeout: float
    ) -> None:
        waiting = ", ".join(rule.explain(error) for rule, error in unmet)
        super().__init__(f"handshake not complete after {timeout:g} s; waiting for: {waiting}")
        self.unmet = tuple(rule for rule, _ in unmet)
        self.timeout = timeout


def _error_text(error: BaseException | None) -> str:
    return f"its check raised {type(error).__name__}: {error}" if error is not None else ""


class HandshakeProgress:
    """The handshake as a state that is checked now and then (no waiting of its own).

    The manager's actor calls :meth:`check` from a timer at the loop rate;
    :func:`wait_for_handshake` calls it in a blocking loop. Each rule is
    logged once when met.
    """

    def __init__(self, rules: Sequence[HandshakeRule], logger: logging.Logger) -> None:
        self.rules = tuple(rules)
        self.pending = list(rules)
        self.errors: dict[str, BaseException | None] = {}
        self.logger = logger
        self.start = time.monotonic()
        if self.pending:
            logger.info("handshake: waiting for %s", ", ".join(r.explain() for r in self.pending))

    def check(self, state: State) -> bool:
        """Evaluate the rules still pending; True once every rule has held."""
        if not self.pending:
            return True
        results = [(rule, *rule.evaluate(state)) for rule in self.pending]
        now = time.monotonic()
        for rule, ok, _ in results:
            if ok:
                self.logger.info("handshake: %s met after %.2f s", rule.name, now - self.start)
        self.pending = [rule for rule, ok, _ in results if not ok]
        self.errors = {rule.name: err for rule, ok, err in results if not ok}
        if not self.pending:
            self.logger.info("handshake complete after %.2f s", now - self.start)
            return True
        return False

    def timeout_error(self, timeout: float) -> HandshakeTimeout:
        """The error naming every rule still unmet."""
        return HandshakeTimeout([(r, self.errors.get(r.name)) for r in self.pending], timeout)


def wait_for_handshake(
    rules: Sequence[HandshakeRule],
    state: State,
    *,
    period: float,
    timeout: float | None,
    sleep: Callable[[float], bool],
    logger: logging.Logger,
) -> bool:
    """Block until every rule holds, checking once per ``period``.

    ``sleep(seconds)`` waits and returns True if the manager was asked to
    stop meanwhile. Returns True when all rules hold, False when stopped;
    raises :class:`HandshakeTimeout` after ``timeout`` seconds (None: never).
    """
    progress = HandshakeProgress(rules, logger)
    while True:
        if progress.check(state):
            return True
        remaining = None if timeout is None else progress.start + timeout - time.monotonic()
        if remaining is not None and remaining <= 0:
            raise progress.timeout_error(timeout)  # type: ignore[arg-type]
        # Never sleep past the timeout, so the last check lands right on it.
        if sleep(period if remaining is None else min(period, remaining)):
            return False
