"""A component's actions as an LLM's tools, run across processes through the events actor.

:func:`register_tools_on` offers methods of other components (Memory's
queries, Vision's ``take_picture``, any method marked with :func:`tool`)
to an :class:`~embagents.components.LLM`. When the model calls one, the LLM's
actor asks the events actor (:class:`~embagents.requests.ToolCall`);
the events actor checks the arguments against the method's signature and
asks the component's actor to run it; the result (or the error, as text)
goes back to the model as the tool's answer. Every hop is a supervised
actor: a component that crashes mid-call answers an error, not a hang.

Example::

    >>> from embagents.components import LLM, Memory
    >>> class Robot:
    ...     name = "robot"
    ...     @tool
    ...     def dock(self, station: str) -> str:
    ...         '''Drive to a charging station.'''
    >>> tool_methods(Robot())
    ['dock']
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from actors import ActorRef
from actors.errors import ActorError
from embagents.requests import EVENTS_ACTOR, ToolCall

__all__ = ["RemoteTool", "register_tools_on", "tool", "tool_methods", "uses_events_actor"]

F = TypeVar("F", bound=Callable[..., Any])
_MARK = "__embagents_tool__"


def tool(fn: F) -> F:
    """Mark a component method as a tool :func:`register_tools_on` offers (it needs a docstring and type hints)."""
    setattr(fn, _MARK, True)
    return fn


def tool_methods(component: Any) -> list[str]:
    """The methods of ``component`` offered as tools: marked with :func:`tool`, else its class's ``llm_tools``."""
    listed = list(getattr(component, "llm_tools", ()))  # in the class's order: the first is shown first
    marked = [name for name, fn in inspect.getmembers(type(component), callable) if getattr(fn, _MARK, False)]
    return listed + [m for m in marked if m not in listed]


class RemoteTool:
    """A callable standing for ``component.method``: calling it asks the events actor to run it.

    Errors (bad arguments, a failing method, an actor that does not answer)
    come back as an ``"error: ..."`` string: it is the model's to read.
    """

    def __init__(self, component: str, method: str, fn: Callable[..., Any], timeout: float = 60.0) -> None:
        self.component, self.method, self.timeout = component, method, timeout
        self.__doc__ = inspect.getdoc(fn)
        self.__signature__ = inspect.signature(fn)  # tool_schema() reads the parameters from it

    def __repr__(self) -> str:
        return f"RemoteTool({self.component!r}, {self.method!r})"

    def __call__(self, **kwargs: Any) -> Any:
        try:
            return ActorRef(EVENTS_ACTOR).ask(ToolCall(self.component, self.method, kwargs)).get(timeout=self.timeout)
        except ActorError as exc:
            why = getattr(exc, "remote_message", None) or str(exc).split("\n")[0]
            kind = getattr(exc, "exc_type", type(exc).__name__)
            return f"error: {kind}: {why}"
        except Exception as exc:  # a timeout: the model may try something else
            return f"error: {type(exc).__name__}: tool {self.method} did not answer within {self.timeout} s ({exc})"


def register_tools_on(llm: Any, *components: Any, methods: Sequence[str] | None = None,
                      timeout: float = 60.0) -> list[str]:
    """Offer ``components``' actions to ``llm`` as tools; returns the tool names added.

    ``methods``: which methods (default: :func:`tool_methods` of each component).
    A tool is named after its method; when two components offer the same method,
    both are named ``<component>_<method>``. Call it in ``system.py`` before the
    system starts (the LLM's config then carries the tools into its actor).

    Example::

        >>> register_tools_on(llm, memory)                          # doctest: +SKIP
        ['between', 'locate', 'near', 'query', 'remember']
    """
    wanted = [(c, m) for c in components for m in (methods or tool_methods(c))]
    counts: dict[str, int] = {}
    for _, m in wanted:
        counts[m] = counts.get(m, 0) + 1
    added = []
    for comp, method in wanted:
        fn = getattr(comp, method, None)
        if not callable(fn) or method.startswith("_"):
            raise ValueError(f"component {comp.name!r} has no public method {method!r}; "
                             f"it offers {', '.join(tool_methods(comp)) or 'no tools'}")
        name = method if counts[method] == 1 else f"{comp.name}_{method}"
        llm.config.tools[name] = RemoteTool(str(comp.name), method, fn, timeout)
        added.append(name)
    return added


def uses_events_actor(component: Any) -> bool:
    """Whether ``component`` needs the events actor: it has remote tools or route actions."""
    tools = getattr(getattr(component, "config", None), "tools", None) or {}
    return any(isinstance(t, RemoteTool) for t in tools.values()) or bool(getattr(component, "route_actions", None))
