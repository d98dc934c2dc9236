"""``embagents call COMPONENT METHOD [ARG ...]``: run a component's action in a running system, from a terminal.

The root of ``embagents supervise`` serves a ``call`` control command
(:func:`call_command`): it checks that the component exists and has that
public method, asks the component's actor (the same
:class:`~embagents.requests.Call` an event's ``call`` action sends,
with the request's deadline: a call still queued then never runs) and
answers with what the method returned, or the method's error in one line
(its remote traceback rides along: ``embagents call -v`` prints it).
:func:`call` is the client side (:mod:`embagents.live` for many calls);
each ``ARG`` is read as JSON when it parses (``3``, ``true``, ``[1, 2]``),
else taken as a string.

Example (examples/vlm.py running)::

    $ embagents call vlm describe camera "What is on the table?"
    vlm.describe -> 'A cup of coffee on a saucer.'
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

from actors import ActorRef
from actors.errors import RemoteError, Timeout
from embagents.components.component import Component
from embagents.components.model_component import ModelComponent
from embagents.live import connect
from embagents.requests import Call

if TYPE_CHECKING:  # for the annotation only: embagents.system imports most of the package
    from embagents.system import System

__all__ = ["BASE_ACTIONS", "actions", "call", "call_command", "parse_args"]


def parse_args(values: Sequence[str]) -> list[Any]:
    """Command-line words as arguments: JSON when they parse, else strings.

    >>> parse_args(["camera", "3", "what is it?", "[1, 2]"])
    ['camera', 3, 'what is it?', [1, 2]]
    """
    out: list[Any] = []
    for v in values:
        try:
            out.append(json.loads(v))
        except ValueError:
            out.append(v)
    return out


#: Methods of the base classes that are actions too (the rest of theirs is the runtime's: hooks, health, wiring).
BASE_ACTIONS = ("change_model_client", "reconfigure")


def actions(component: Any) -> list[str]:
    """The actions of ``component``: public methods its own classes add, and :data:`BASE_ACTIONS`.

    Hooks (``on_activate``), health setters (``set_system_failure``) and the
    rest of :class:`~embagents.components.Component`'s machinery are not listed.
    """

    base = set(dir(ModelComponent)) | set(dir(Component)) | {"chat_stream"}  # a generator: the LLM's stream, no action
    return sorted(n for n in dir(type(component)) if not n.startswith("_") and (n not in base or n in BASE_ACTIONS)
                  and callable(getattr(component, n, None)))


def call_command(asys: Any, system: System) -> Callable[[dict[str, Any]], dict[str, Any]]:
    """The root's handler of ``{"cmd": "call", "component", "method", "args", "kwargs", "timeout"}``."""

    def handle(req: dict[str, Any]) -> dict[str, Any]:
        name, method = req.get("component"), req.get("method")
        by_name = {str(c.name): c for c in system.components}
        comp = by_name.get(name) if isinstance(name, str) else None
        if comp is None or not isinstance(name, str):
            return {"ok": False, "error": f"system {system.name!r} has no component {name!r}; "
                    f"its components: {', '.join(sorted(by_name)) or 'none'}"}
        if not isinstance(method, str) or method.startswith("_") or not callable(getattr(comp, method, None)):
            return {"ok": False, "error": f"component {name!r} ({type(comp).__name__}) has no action {method!r}; "
                    f"its actions: {', '.join(actions(comp)) or 'none'}"}
        args, kwargs = req.get("args") or [], req.get("kwargs") or {}
        timeout = float(req.get("timeout") or 60.0)
        if req.get("deadline") is not None:  # the caller stops waiting then: so does the ask
            timeout = max(0.001, min(timeout, req["deadline"] - time.monotonic()))
        # The Call carries the ask's deadline: behind a slow call in the mailbox past it, it never runs.
        call = Call(method, list(args), dict(kwargs), deadline=time.monotonic() + timeout)
        try:
            result = ActorRef(name).ask(call, timeout=timeout).get()
        except RemoteError as exc:  # the method raised: its type and message; the traceback for -v
            return {"ok": False, "error": f"{name}.{method} failed: {exc.exc_type}: {exc.remote_message}",
                    "traceback": exc.remote_traceback}
        except Timeout:
            return {"ok": False, "error": f"{name}.{method} did not answer within {timeout:.3g} s (if it had "
                    "started it may still be running; if not, it will not start)"}
        except Exception as exc:  # the actor died, or is not there
            return {"ok": False, "error": f"{name}.{method} failed: {type(exc).__name__}: {exc}"}
        try:
            json.dumps(result)
        except (TypeError, ValueError):
            result = repr(result)
        return {"ok": True, "result": result}

    return handle


def call(component: str, method: str, args: Sequence[Any] = (), kwargs: dict[str, Any] | None = None, *,
         run: str | None = None, timeout: float = 60.0) -> dict[str, Any]:
    """Call ``component.method(*args, **kwargs)`` in the live run ``run`` (default: the only one).

    One call, one connection: a script making many uses :func:`embagents.live.connect`.
    Raises ``supervisor.client.ControlError`` with the root's reason (no run, unknown
    component or method, the method's own error: its traceback in ``err.reply["traceback"]``).
    """

    msg = {"cmd": "call", "component": component, "method": method, "args": list(args),
           "kwargs": dict(kwargs or {}), "timeout": timeout}
    with connect(run) as live:
        reply = live.request(msg, timeout + 5.0)  # the root answers a timeout itself, at `timeout`
        return {**reply, "run_id": live.run_id, "system": live.system}
