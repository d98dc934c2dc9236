"""What every compat module shares: the refusal, the offline switch, the warning printed once.

Example::

    >>> unsupported("LLMConfig(enable_rag=True) (RAG)", "a Memory component")
    Traceback (most recent call last):
    embagents.compat._core.CompatError: EmbodiedAgents' LLMConfig(enable_rag=True) (RAG) is not supported by embagents; use a Memory component
"""

from __future__ import annotations

import os
import socket
import sys
from typing import NoReturn

__all__ = ["CompatError", "note", "offline", "reachable", "unsupported"]

_said: set[str] = set()


class CompatError(ValueError):
    """An EmbodiedAgents feature embagents does not have; the message names it and what to use here."""


def unsupported(feature: str, instead: str) -> NoReturn:
    """Refuse ``feature`` in one line naming what to use here."""
    raise CompatError(f"EmbodiedAgents' {feature} is not supported by embagents; use {instead}")


def offline() -> bool:
    """``--offline`` on the command line or ``EMBAGENTS_OFFLINE=1``: model servers are replaced by local defaults."""
    return "--offline" in sys.argv or os.environ.get("EMBAGENTS_OFFLINE", "").lower() in ("1", "true", "yes")


def note(text: str) -> None:
    """Say ``text`` on stderr once per process (a file loaded twice says it once)."""
    if text not in _said:
        _said.add(text)
        print(f"embagents.compat: {text}", file=sys.stderr, flush=True)


def reachable(host: str, port: int, timeout: float = 0.3) -> bool:
    """Whether something listens on ``host:port`` (one TCP connect, ``timeout`` seconds at most)."""
    try:
        with socket.create_connection((host, int(port)), timeout=timeout):
            return True
    except OSError:
        return False
