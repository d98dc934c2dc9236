"""``ros_sugar.core``: Action, Event, ComponentFallbacks, BaseComponent (an embagents Component).

Example::

    >>> fb = ComponentFallbacks(on_algorithm_fail=None, max_retries=2)
    >>> fb.max_retries
    2
"""

from __future__ import annotations

from typing import Any

from embagents.compat._core import unsupported
from embagents.compat.agents.ros import Action, Event
from embagents.components import Component as BaseComponent
from embagents.events import Fallback

__all__ = ["Action", "BaseComponent", "ComponentFallbacks", "Event"]


def ComponentFallbacks(on_any_fail: Any = None, on_algorithm_fail: Any = None,  # noqa: N802 - Sugarcoat's name
                       on_component_fail: Any = None, on_system_fail: Any = None, on_giveup: Any = None,
                       max_retries: int | None = None) -> Fallback:
    """Sugarcoat's fallbacks as an embagents :class:`~embagents.events.Fallback` (``fallback=`` of a component)."""

    if on_giveup is not None:
        unsupported("ComponentFallbacks(on_giveup=...)", "an Event on the component's Health, or restart()")
    return Fallback(on_algorithm_fail=on_algorithm_fail or on_any_fail,
                    on_component_fail=on_component_fail or on_any_fail,
                    on_system_fail=on_system_fail or on_any_fail, max_retries=3 if max_retries is None else max_retries)
