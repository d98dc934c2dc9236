"""The package's front: what a system.py imports, and the old module paths that keep working one release."""

from __future__ import annotations

import subprocess
import sys

import pytest

import embagents


def _run(code: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-W", "always::FutureWarning", "-c", code],
                          capture_output=True, text=True, timeout=120)


def test_system_stop_imported_from_the_old_launcher_path_works_and_warns_where_it_is_now() -> None:
    out = _run("from embagents.launch import SYSTEM_STOP; print(SYSTEM_STOP)")
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "system_stop"
    assert "import SYSTEM_STOP from embagents.system" in out.stderr


@pytest.mark.parametrize("old", sorted(embagents.MOVED_MODULES))
def test_every_moved_module_imports_from_its_old_path_with_a_warning_naming_the_new(old: str) -> None:
    new = embagents.MOVED_MODULES[old]
    out = _run(f"import importlib, {new} as new\n"
               f"old = importlib.import_module({old!r})\n"
               "names = getattr(new, '__all__', [n for n in vars(new) if not n.startswith('_')])\n"
               "assert names and all(getattr(old, n) is getattr(new, n) for n in names), names\n")
    assert out.returncode == 0, out.stderr
    assert "FutureWarning" in out.stderr and old in out.stderr


def test_a_submodule_of_a_moved_package_is_found_at_its_old_path() -> None:
    out = _run("from embagents.clients.openai_http import OpenAIHTTPError; print(OpenAIHTTPError.__module__)")
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "embagents.models.clients.openai_http"


def test_a_module_that_never_existed_is_still_an_import_error() -> None:
    with pytest.raises(ModuleNotFoundError):
        __import__("embagents.no_such_module")
