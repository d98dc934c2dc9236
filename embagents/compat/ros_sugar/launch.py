"""``ros_sugar.launch``: Launcher."""

from embagents.compat.agents.ros import Launcher

__all__ = ["Launcher"]
