"""Frame kinds and small constants shared by both ends of a mailbox link.

A sender's DEALER sends ``[kind, seq, body]`` (TELL, ASK, CTRL) and
``[RELEASE, names]``; the actor's ROUTER answers with ``[REPLY, seq, ok,
value]``, ``[ACK, upto_seq]``, ``[RELEASE, names]`` and ``[DEAD, seq,
reason]``. Every frame is one msgpack document (see :mod:`actors.codec`).
"""

from __future__ import annotations

import re

TELL, ASK, REPLY, ACK, RELEASE, DEAD, CTRL = range(7)

NAME_RE = re.compile(r"^[A-Za-z0-9_.\-]{1,64}$")


def check_name(name: str) -> str:
    """Validate an actor or topic name (it becomes part of a socket path)."""
    if not isinstance(name, str) or not NAME_RE.match(name):
        raise ValueError(
            f"invalid name {name!r}: use 1-64 letters, digits, '_', '.' or '-' "
            "(it becomes part of a socket path)"
        )
    return name
