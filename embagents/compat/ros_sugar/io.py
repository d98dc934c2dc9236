"""``ros_sugar.io``: Topic (an embagents Topic with ``.msg`` conditions)."""

from embagents.compat.agents.ros import FixedInput, Topic

__all__ = ["FixedInput", "Topic"]
