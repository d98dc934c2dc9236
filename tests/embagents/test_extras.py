"""embagents.extras: which extra installs a module, for the errors that name what to install."""

from __future__ import annotations

import re
from importlib import metadata

from embagents.extras import AGGREGATE_EXTRAS, import_name, install_hint
from tests.helpers import pyproject_extras


def test_each_installed_distribution_of_an_extra_is_known_by_the_name_it_is_imported_as() -> None:
    provides: dict[str, set[str]] = {}
    for module, dists in metadata.packages_distributions().items():
        for d in dists:
            provides.setdefault(re.sub(r"[-_.]+", "-", d).lower(), set()).add(module)
    checked = 0
    for extra, requirements in pyproject_extras().items():
        if not extra or extra in AGGREGATE_EXTRAS:
            continue
        for req in requirements:
            dist = re.sub(r"[-_.]+", "-", re.match(r"[A-Za-z0-9][A-Za-z0-9._-]*", req)[0]).lower()  # type: ignore[index]
            if dist in provides and dist != "embagents":
                top = import_name(dist).split(".")[0]
                assert top in provides[dist], f"extra {extra!r}: {dist} is imported as one of {sorted(provides[dist])}, " \
                                              f"not {top!r}: add it to embagents.extras._IMPORT_NAMES"
                checked += 1
    assert checked >= 10  # most extras are installed where the tests run (CI installs them all)


def test_the_hint_names_the_extra_or_says_none_has_the_module() -> None:
    assert install_hint("sounddevice") == "pip install 'embagents[speech]'"
    assert install_hint("google.protobuf.message") == install_hint("google") == "pip install 'embagents[tools]' (also in: vla)"
    assert install_hint("no_such_module.sub") == "pip install no_such_module (no extra of embagents installs it)"
