"""Exit statuses read as OTP exit reasons."""

from __future__ import annotations

import signal

from supervisor.exits import Exit, classify


def test_classify() -> None:
    assert classify(0) == Exit("normal", 0, "exit code 0")
    assert classify(0, requested=True).reason == "shutdown"
    assert classify(-signal.SIGTERM).reason == "shutdown"
    assert classify(-signal.SIGKILL).reason == "killed"
    assert classify(-signal.SIGKILL, requested=True).reason == "killed"
    segv = classify(-signal.SIGSEGV)
    assert (segv.reason, segv.detail, segv.normal) == ("error", "killed by SIGSEGV", False)
    assert classify(3, "ValueError: x").detail == "exit code 3: ValueError: x"
    assert classify(None).reason == "error"
    assert classify(0).normal and classify(-15).normal and not classify(-9).normal
    assert str(classify(-9)) == "killed (killed by SIGKILL)"
