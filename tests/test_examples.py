"""Every example system passes `embagents check`."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).parents[1] / "examples"


@pytest.mark.parametrize("name", ["chat.py", "ros_chat.py"])
def test_example_systems_check_clean(name: str) -> None:
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "check", str(EXAMPLES / name)],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    assert out.stdout.startswith("OK:")
