"""EmbodiedAgents' ``agents`` package on embagents: ``components``, ``models``, ``clients``, ``config``, ``ros``.

``from agents.components import LLM`` becomes ``from embagents.compat.agents.components import LLM``;
see :mod:`embagents.compat` and docs/porting.md.
"""
