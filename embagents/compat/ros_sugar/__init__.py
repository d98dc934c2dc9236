"""Sugarcoat's ``ros_sugar`` on embagents: ``Launcher`` here, ``core`` (Action, Event, ComponentFallbacks...),
``io`` (Topic), ``launch`` (Launcher), ``actions`` (Action).

``from ros_sugar import Launcher`` becomes ``from embagents.compat.ros_sugar import Launcher``.
"""

from embagents.compat.agents.ros import Launcher

__all__ = ["Launcher"]
