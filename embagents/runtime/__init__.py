"""Actors that run a System: component actors and local model actors."""

from embagents.runtime.component_actor import ComponentActor
from embagents.runtime.model_actor import LlamaModelActor

__all__ = ["ComponentActor", "LlamaModelActor"]
