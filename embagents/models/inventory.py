"""The models a system runs: declared ones and those its components' clients name.

Example::

    >>> from embagents.models import LlamaModel
    >>> from embagents.system import System
    >>> models_of(System([], models=[LlamaModel(name="smollm2")], name="demo"))[0].name
    'smollm2'
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from embagents.models.client import LocalModelClient
from embagents.models.declarations import Model

if TYPE_CHECKING:  # for the annotation only: embagents.system imports most of the package
    from embagents.system import System

__all__ = ["models_of"]


def models_of(system: System) -> list[Model]:
    """Every model ``system`` declares or a component's client refers to, once each.

    Raises ``ValueError`` for a client whose model the system does not declare.
    """
    found: dict[str, Model] = {}
    for m in system.models:
        if isinstance(m, Model):
            found.setdefault(m.name, m)
    for c in system.components:
        for client in getattr(c, "clients", {}).values():
            # A LocalModelClient, or another client of a model actor of this run (a LocalPolicyClient).
            if (isinstance(client, LocalModelClient) or hasattr(client, "model")) and getattr(client, "in_run", False):
                model = client.model or found.get(client.name)
                if model is None:
                    raise ValueError(
                        f"component {c.name!r} uses model {client.name!r}, which the system does not declare: "
                        "pass the model (e.g. LlamaModel) to LocalModelClient or to System(models=[...])"
                    )
                found.setdefault(model.name, model)
    return list(found.values())
