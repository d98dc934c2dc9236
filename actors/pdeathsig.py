"""No orphans: a child process asks the kernel to kill it when its parent dies.

``PR_SET_PDEATHSIG`` (Linux) sends a signal to a process the moment its
parent exits, even on SIGKILL. The one race, the parent dying between the
``fork()`` and the ``prctl()``, is closed by checking the parent pid
afterwards. Used by actor processes (children of the fork server) and by
supervised external programs (in ``preexec_fn``, before ``exec``).

libc's ``prctl`` is resolved once, at import: after ``fork()`` in a threaded
parent, ``dlopen()`` could deadlock on a lock another thread held.

Example::

    >>> import os
    >>> die_with_parent(os.getppid())   # returns: our parent is alive
"""

from __future__ import annotations

import ctypes
import os
import signal
from typing import Any

__all__ = ["die_with_parent"]

_PR_SET_PDEATHSIG = 1

try:
    _prctl: Any = ctypes.CDLL(None, use_errno=True).prctl
except (OSError, AttributeError):  # not Linux: the fork server's EOF path still cleans up
    _prctl = None


def die_with_parent(parent_pid: int, sig: int = signal.SIGKILL) -> None:
    """Have ``sig`` sent to this process when its parent dies; exit now if ``parent_pid`` already has.

    Call it in the child right after ``fork()``; ``parent_pid`` is the
    parent's pid read before the fork. Only async-signal-safe work happens
    here, so it is fit for ``subprocess.Popen(preexec_fn=...)``.
    """
    if _prctl is not None:
        _prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
    if os.getppid() != parent_pid:  # the parent died before prctl took effect: we were reparented
        os._exit(1)
