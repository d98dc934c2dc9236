"""The API reference pages: every module of a package, documented from its docstrings.

A page under ``api/`` says which packages it holds with a marker line::

    <!-- automodules embagents.models embagents.models.backends -->

At build time the marker becomes, for each package, a section for the package and one for each of
its modules (``automodule`` with the project's autodoc options), so a new module appears without
an edit here. A package of ``actors``, ``supervisor`` or ``embagents`` that no page names is a
warning (an error under ``-W``) naming the fix: the reference keeps up with the tree.

Example::

    >>> print(render(["actors.credits"]).splitlines()[0])
    ## `actors.credits`
"""

from __future__ import annotations

import importlib
import pkgutil
import re
from typing import Any

from sphinx.application import Sphinx
from sphinx.util import logging

ROOTS = ("actors", "supervisor", "embagents")
MARKER = re.compile(r"^<!-- automodules ([\w. ]+) -->$", re.M)
logger = logging.getLogger(__name__)


def modules_of(package: str) -> list[str]:
    """``package`` and its direct modules (not subpackages: they have a section of their own)."""
    pkg = importlib.import_module(package)
    names = [package]
    if hasattr(pkg, "__path__"):
        names += sorted(f"{package}.{m.name}" for m in pkgutil.iter_modules(pkg.__path__)
                        if not m.ispkg and m.name != "__main__")
    return names


def packages() -> list[str]:
    """Every package of the three roots."""
    found = []
    for root in ROOTS:
        pkg = importlib.import_module(root)
        found.append(root)
        found += [m.name for m in pkgutil.walk_packages(pkg.__path__, root + ".") if m.ispkg]
    return found


def render(names: list[str]) -> str:
    """MyST for one section per module (autodoc writes reST: it runs inside ``eval-rst``)."""
    return "\n".join(f"## `{n}`\n\n```{{eval-rst}}\n.. automodule:: {n}\n```\n" for n in names)


def _source_read(app: Sphinx, docname: str, source: list[str]) -> None:
    if not docname.startswith("api/"):
        return

    def expand(m: re.Match[str]) -> str:
        pkgs = m[1].split()
        app.env.apipages_named.update(pkgs)  # type: ignore[attr-defined]
        return "\n".join(render(modules_of(p)) for p in pkgs)

    source[0] = MARKER.sub(expand, source[0])


def _check_coverage(app: Sphinx, env: Any) -> None:
    named = getattr(env, "apipages_named", set())
    for pkg in packages():
        if pkg not in named:
            logger.warning(f"API reference: package {pkg} is on no page; add it to a "
                           f"`<!-- automodules ... -->` line of a page in docs/api/")


def _env_init(app: Sphinx, env: Any, docnames: Any) -> None:
    if not hasattr(env, "apipages_named"):
        env.apipages_named = set()


def setup(app: Sphinx) -> dict[str, Any]:
    app.connect("env-before-read-docs", _env_init)
    app.connect("source-read", _source_read)
    app.connect("env-updated", _check_coverage)
    return {"parallel_read_safe": False, "parallel_write_safe": True}
