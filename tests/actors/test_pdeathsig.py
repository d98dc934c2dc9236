"""die_with_parent: a child dies with its parent, and one whose parent is already gone exits at once."""

from __future__ import annotations

import signal
import subprocess
import sys

import psutil

# A parent that forks one child; the child asks to die with it, prints its pid and sleeps.
PARENT = """
import os, sys, time
from actors import die_with_parent
parent = os.getpid()
pid = os.fork()
if pid == 0:
    die_with_parent(parent)
    print(os.getpid(), flush=True)
    time.sleep(60)
    os._exit(0)
time.sleep(60)
"""


def test_a_child_dies_with_its_sigkilled_parent() -> None:
    parent = subprocess.Popen([sys.executable, "-c", PARENT], stdout=subprocess.PIPE, text=True)
    try:
        assert parent.stdout is not None
        child = psutil.Process(int(parent.stdout.readline()))
        assert child.ppid() == parent.pid
    finally:
        parent.send_signal(signal.SIGKILL)
        parent.wait(10)
    child.wait(10)  # psutil.TimeoutExpired if the child outlived its parent


def test_a_child_whose_parent_already_died_exits_at_once() -> None:
    # The race the parent-pid check closes: the parent died between fork() and prctl().
    code = "from actors import die_with_parent; die_with_parent(os.getppid() + 1); print('survived')"
    out = subprocess.run([sys.executable, "-c", "import os; " + code], capture_output=True, text=True, timeout=30)
    assert out.returncode == 1 and "survived" not in out.stdout
