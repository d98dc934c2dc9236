"""``ros_sugar.actions``: Action."""

from embagents.compat.agents.ros import Action

__all__ = ["Action"]
