"""Why a child ended: OTP's exit reasons, read from a process's exit status.

============  ==========================================================  =======
reason        when                                                        normal?
============  ==========================================================  =======
normal        exit code 0 (the actor stopped itself, a program ended)     yes
shutdown      it died of SIGTERM, or ended after its supervisor's stop    yes
killed        SIGKILL (brutal_kill, a shutdown timeout, or anyone else)   no
error         any other exit code or signal, a hang, a resource limit     no
============  ==========================================================  =======

Only the "normal" reasons spare a transient child its restart.

Example::

    >>> classify(0), classify(-15).reason, classify(-11).detail
    (Exit(reason='normal', code=0, detail='exit code 0'), 'shutdown', 'killed by SIGSEGV')
"""

from __future__ import annotations

import signal
from dataclasses import dataclass

__all__ = ["Exit", "classify"]


@dataclass(frozen=True)
class Exit:
    """How one incarnation of a child ended."""

    reason: str  # normal | shutdown | killed | error
    code: int | None = None
    detail: str = ""

    @property
    def normal(self) -> bool:
        return self.reason in ("normal", "shutdown")

    def __str__(self) -> str:
        return f"{self.reason} ({self.detail})" if self.detail else self.reason


def _signame(sig: int) -> str:
    try:
        return signal.Signals(sig).name
    except ValueError:
        return f"signal {sig}"


def classify(code: int | None, failure: str | None = None, *, requested: bool = False) -> Exit:
    """The :class:`Exit` of a process that ended with ``code`` (negative: killed by a signal).

    ``requested``: its supervisor asked it to stop, so a clean end is "shutdown".
    """
    if code is None:
        return Exit("error", None, failure or "unknown exit")
    if code < 0:
        detail = f"killed by {_signame(-code)}"
        if requested and -code in (signal.SIGTERM, signal.SIGKILL):
            return Exit("shutdown" if -code == signal.SIGTERM else "killed", code, detail)
        if -code == signal.SIGTERM:
            return Exit("shutdown", code, detail)
        return Exit("killed" if -code == signal.SIGKILL else "error", code, detail)
    if code == 0:
        return Exit("shutdown" if requested else "normal", 0, "exit code 0")
    detail = f"exit code {code}" + (f": {failure}" if failure else "")
    return Exit("error", code, detail)
