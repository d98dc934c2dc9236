"""EmbodiedAgents recipes on embagents, with only their import lines changed.

``embagents.compat.agents`` (its ``components``, ``models``, ``clients``,
``config`` and ``ros`` modules) and ``embagents.compat.ros_sugar`` take
EmbodiedAgents' spellings and build embagents objects::

    from agents.components import LLM          ->  from embagents.compat.agents.components import LLM
    from ros_sugar.core import ComponentFallbacks  ->  from embagents.compat.ros_sugar.core import ComponentFallbacks

``Launcher().bringup()`` registers the System when ``embagents check`` or
``embagents supervise`` loads the file, and supervises it when the file is run
as ``python recipe.py``. Model servers (Ollama, any OpenAI-compatible one) are
reached through :class:`~embagents.models.clients.OpenAIHTTPClient`; RoboML-served
models run here as local model actors. ``--offline`` (or ``EMBAGENTS_OFFLINE=1``,
or a config's ``enable_local_model=True`` with no server listening) replaces a
server's model by the offline default, with a warning naming what was replaced.
What embagents does not do (RAG, for one) is refused in one line naming the
feature and what to use here. docs/porting.md is the guide.
"""

from embagents.compat._core import CompatError, offline

__all__ = ["CompatError", "offline"]
