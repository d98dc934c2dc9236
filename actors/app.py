"""The name of the application built on the actors: set by the layer above, used for what users see.

The actors know nothing of the application that uses them; it names itself
once, at import, and the name appears in process titles
(``<app>:<actor>``), in the private folder's name and in the environment
variables that override folders (``<APP>_RUN_BASE``, ``<APP>_RUNS_DIR``).

Example::

    >>> before = app_name()
    >>> set_app_name("robot")
    >>> app_name(), env_name("RUN_BASE")
    ('robot', 'ROBOT_RUN_BASE')
    >>> set_app_name(before)
"""

from __future__ import annotations

import os
import re

__all__ = ["app_name", "env", "env_name", "set_app_name"]

_name = "actors"
_VALID = re.compile(r"[a-z][a-z0-9_]{0,31}")


def set_app_name(name: str) -> None:
    """Name the application (lower case letters, digits and ``_``, starting with a letter)."""
    global _name
    if not isinstance(name, str) or not _VALID.fullmatch(name):
        raise ValueError(f"app name {name!r} must be 1-32 lower-case letters, digits or '_', starting with a letter; e.g. 'embagents'")
    _name = name


def app_name() -> str:
    """The application's name ("actors" until the layer above sets it)."""
    return _name


def env_name(var: str) -> str:
    """The environment variable ``<APP>_<var>``."""
    return f"{_name.upper()}_{var}"


def env(var: str) -> str | None:
    """The value of ``<APP>_<var>`` (None if unset or empty)."""
    return os.environ.get(env_name(var)) or None
