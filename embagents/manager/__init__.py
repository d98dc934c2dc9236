"""The manager main loop: fixed-rate ticks over handlers and a shared state.

For users of the ROS Base style. A :class:`Manager` waits for its handshake
rules, then runs its handlers at a fixed rate; nodes and pykka agents can
be attached to share its process, and are released in reverse order. In a
System (``System(managers=[...])``) it is a supervised actor: :class:`Node`
objects reach topics, :class:`Agent` objects run attached or isolated.

Example::

    >>> from embagents.manager import HandshakeRule, Manager
    >>> manager = Manager(50, handshake=[HandshakeRule.has_value("goal")])
    >>> manager.state.goal = (1.0, 2.0)
    >>> manager.add_handler(lambda state, tick: state.update(ticks=tick))  # doctest: +ELLIPSIS
    <function <lambda> at ...>
    >>> manager.run(max_ticks=2), manager.state.ticks
    (2, 2)
"""

from embagents.manager.agents import Agent, AgentCrashed, AgentError, AgentFuture, AgentNotRunning
from embagents.manager.attached import AttachedActor, AttachedNode, Resource
from embagents.manager.handler import (
    FunctionHandler,
    Handler,
    InvalidTransition,
    StateMachineHandler,
)
from embagents.manager.handshake import HandshakeRule, HandshakeTimeout
from embagents.manager.loop import ErrorPolicy, Manager, RestartPolicy
from embagents.manager.nodes import Node, NodeNotBound
from embagents.manager.state import State

__all__ = [
    "Agent",
    "AgentCrashed",
    "AgentError",
    "AgentFuture",
    "AgentNotRunning",
    "AttachedActor",
    "AttachedNode",
    "ErrorPolicy",
    "FunctionHandler",
    "Handler",
    "HandshakeRule",
    "HandshakeTimeout",
    "InvalidTransition",
    "Manager",
    "Node",
    "NodeNotBound",
    "Resource",
    "RestartPolicy",
    "State",
    "StateMachineHandler",
]
