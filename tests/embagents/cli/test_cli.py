"""The ``embagents`` command line itself (subcommands have their own test modules)."""

from __future__ import annotations

import subprocess
import sys
from importlib.metadata import version


def test_version_prints_the_installed_version() -> None:
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "--version"], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0
    assert out.stdout.strip() == f"embagents {version('embagents')}"
