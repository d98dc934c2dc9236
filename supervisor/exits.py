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

    >>> classify(0)
    Exit(reason=<Reason.NORMAL: 'normal'>, code=0, detail='exit code 0')
    >>> classify(-15).reason == "shutdown", str(classify(-11))
    (True, 'error (killed by SIGSEGV)')
"""

from __future__ import annotations

import signal
from dataclasses import dataclass

from supervisor.states import StrEnum

__all__ = ["Exit", "Reason", "classify"]


class Reason(StrEnum):
    """Why a child ended (the table above)."""

    NORMAL = "normal"
    SHUTDOWN = "shutdown"
    KILLED = "killed"
    ERROR = "error"


@dataclass(frozen=True)
class Exit:
    """How one incarnation of a child ended."""

    reason: Reason
    code: int | None = None
    detail: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "reason", Reason(self.reason))  # a plain string is checked

    @property
    def normal(self) -> bool:
        return self.reason in (Reason.NORMAL, Reason.SHUTDOWN)

    def __str__(self) -> str:
        return f"{self.reason} ({self.detail})" if self.detail else str(self.reason)


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
        return Exit(Reason.ERROR, None, failure or "unknown exit")
    if code < 0:
        detail = f"killed by {_signame(-code)}"
        if requested and -code in (signal.SIGTERM, signal.SIGKILL):
            return Exit(Reason.SHUTDOWN if -code == signal.SIGTERM else Reason.KILLED, code, detail)
        if -code == signal.SIGTERM:
            return Exit(Reason.SHUTDOWN, code, detail)
        return Exit(Reason.KILLED if -code == signal.SIGKILL else Reason.ERROR, code, detail)
    if code == 0:
        return Exit(Reason.SHUTDOWN if requested else Reason.NORMAL, 0, "exit code 0")
    detail = f"exit code {code}" + (f": {failure}" if failure else "")
    return Exit(Reason.ERROR, code, detail)
