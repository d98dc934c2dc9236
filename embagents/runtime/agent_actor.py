"""Runs one isolated agent of a manager as an actor process of its own.

The System was loaded before the fork server started, so the agent's
declaration is already in memory: the actor finds it by manager and agent
name, builds the agent's object here and answers each
:class:`~embagents.requests.Call` with the method's return value
(an exception reaches the caller's future as an error naming the agent).

Example::

    >>> AgentActor("system.py", "pick_place", "detector").label      # doctest: +SKIP
    "agent 'detector' of manager 'pick_place'"
"""

from __future__ import annotations

from typing import Any

from actors import Actor
from embagents.manager.agents import invoke
from embagents.requests import Call
from embagents.system import loaded_system

__all__ = ["AgentActor"]


class AgentActor(Actor):
    """Hosts agent ``agent`` of manager ``manager`` of the system loaded from ``system_path``."""

    def __init__(self, system_path: str, manager: str, agent: str) -> None:
        self.system_path = system_path
        self.manager_name = manager
        self.agent_name = agent
        self.label = f"agent {agent!r} of manager {manager!r}"

    def on_start(self) -> None:
        decl = loaded_system(self.system_path).manager(self.manager_name).agent(self.agent_name)
        self.obj = decl.build()

    def on_receive(self, message: Any) -> Any:
        if not isinstance(message, Call):
            raise ValueError(f"{self.label}: expected a Call(method, args, kwargs), got {message!r}")
        return invoke(self.agent_name, self.obj, message.method, message.args, message.kwargs)

    def on_stop(self) -> None:
        closer = getattr(self.obj, "close", None)
        if callable(closer):
            closer()
