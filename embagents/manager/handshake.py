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

import attrs

from embagents.manager.state import State

__all__ = ["HandshakeRule", "HandshakeTimeout", "wait_for_handshake"]


@attrs.frozen
class HandshakeRule:
    """A named condition over the shared state, described for humans."""

    name: str
    predicate: Callable[[State], bool]
    description: str = ""

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
    start = time.monotonic()
    pending = list(rules)
    if pending:
        logger.info("handshake: waiting for %s", ", ".join(r.explain() for r in pending))
    while True:
        results = [(rule, *rule.evaluate(state)) for rule in pending]
        now = time.monotonic()
        for rule, ok, _ in results:
            if ok:
                logger.info("handshake: %s met after %.2f s", rule.name, now - start)
        pending = [rule for rule, ok, _ in results if not ok]
        if not pending:
            if rules:
                logger.info("handshake complete after %.2f s", now - start)
            return True
        remaining = None if timeout is None else start + timeout - now
        if remaining is not None and remaining <= 0:
            raise HandshakeTimeout([(r, err) for r, ok, err in results if not ok], timeout)
        # Never sleep past the timeout, so the last check lands right on it.
        if sleep(period if remaining is None else min(period, remaining)):
            return False
