"""The project's own checks, run as tests so CI (the README's test command) keeps them passing.

- ruff over the whole tree;
- the doctests of ``actors``, ``supervisor`` and ``embagents`` (every
  module's example runs, or says ``# doctest: +SKIP`` because it needs a run);
- the import contracts of ``pyproject.toml`` (import-linter): the layers
  ``embagents -> supervisor -> actors``, rclpy only in ``embagents.ros``, no
  import cycles inside a package;
- mypy over ``actors``, ``supervisor`` and ``embagents`` (``[tool.mypy]`` in ``pyproject.toml``),
  with no module's errors ignored (the list issue 28 started with is empty; it stays so).

Each runs as its own process from the project root, as a developer would run it.
"""

from __future__ import annotations

import os
import subprocess
import sys

if sys.version_info >= (3, 11):
    import tomllib
else:  # a dependency below 3.11 (pyproject.toml)
    import tomli as tomllib

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


def test_the_packages_type_check() -> None:
    _run("-m", "mypy")


# The modules of ``[[tool.mypy.overrides]] ignore_errors``: embagents joined mypy with 36 (issue 28), all typed
# since. Never raise it: type the new code instead.
MYPY_IGNORED_AT_MOST = 0


def test_the_mypy_ignore_list_only_shrinks() -> None:
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        overrides = tomllib.load(f)["tool"]["mypy"].get("overrides", [])
    ignored = [m for o in overrides if o.get("ignore_errors") for m in o["module"]]
    assert len(ignored) <= MYPY_IGNORED_AT_MOST, (
        f"{len(ignored)} modules have their type errors ignored, more than {MYPY_IGNORED_AT_MOST}: type the new "
        f"module instead of adding it to [[tool.mypy.overrides]] in pyproject.toml")
    gone = [m for m in ignored if not any(os.path.exists(os.path.join(ROOT, *m.split(".")) + ext)
                                          for ext in (".py", "/__init__.py"))]
    assert not gone, f"the mypy ignore list names modules that are not there (moved or removed?): {gone}"
