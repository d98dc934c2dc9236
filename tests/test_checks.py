"""The project's own checks, run as tests so CI (the README's test command) keeps them passing.

- ruff over the whole tree;
- the doctests of ``actors``, ``supervisor`` and ``embagents`` (every
  module's example runs, or says ``# doctest: +SKIP`` because it needs a run);
- the import contracts of ``pyproject.toml`` (import-linter): the layers
  ``embagents -> supervisor -> actors``, rclpy only in ``embagents.ros``, no
  import cycles inside a package;
- mypy over ``actors`` and ``supervisor`` (``[tool.mypy]`` in ``pyproject.toml``).

Each runs as its own process from the project root, as a developer would run it.
"""

from __future__ import annotations

import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _run(*argv: str) -> None:
    proc = subprocess.run([sys.executable, *argv], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"`{' '.join(argv)}` failed (exit {proc.returncode}):\n{proc.stdout[-6000:]}\n{proc.stderr[-3000:]}"


def test_ruff_finds_nothing_to_fix() -> None:
    _run("-m", "ruff", "check", ".")


def test_every_doctest_of_the_packages_passes() -> None:
    _run("-m", "pytest", "--doctest-modules", "actors", "supervisor", "embagents", "-q", "-p", "no:cacheprovider")


def test_imports_keep_the_layers_and_have_no_cycles() -> None:
    _run("-c", "import sys; from importlinter.cli import lint_imports_command; sys.exit(lint_imports_command())")


def test_actors_and_supervisor_type_check() -> None:
    _run("-m", "mypy")
