"""Actors that run a System: component actors and local model actors."""

from embagents.models.actor import LlamaModelActor
from embagents.runtime.component_actor import ComponentActor

__all__ = ["ComponentActor", "LlamaModelActor"]
