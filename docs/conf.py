"""Sphinx configuration of the embagents documentation (MyST Markdown pages, autodoc API reference).

Build it as CI does (tests/test_docs.py), warnings as errors::

    pip install -e ".[docs]"
    sphinx-build -W -b html docs /tmp/embagents-docs
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # the packages of this checkout, not an installed copy
sys.path.insert(0, str(HERE / "_ext"))

project = "embagents"
author = "the embagents authors"
copyright = "the embagents authors, MIT licence"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "benchpage",  # docs/_ext/benchpage.py: the benchmark page from docs/bench/*.json
    "apipages",  # docs/_ext/apipages.py: one API page per package, every module on it
]

source_suffix = {".md": "markdown"}
exclude_patterns = ["_build", "bench", "speech_vad.py"]
root_doc = "index"

# MyST: `page.md#a-heading` links resolve (and are checked: a missing one is a warning, so an error).
myst_heading_anchors = 4
myst_enable_extensions = ["colon_fence"]

# The API reference: every public module's docstrings, members in source order.
# A package's __init__ re-exports its modules' names: each is documented once, in its own module.
autodoc_default_options = {"members": True, "show-inheritance": True, "member-order": "bysource",
                           "ignore-module-all": True}
autodoc_typehints = "description"
autodoc_typehints_format = "short"
# Optional heavy libraries are imported lazily by the modules that use them; the ones imported at
# module level by a backend are mocked so the reference builds with the base install.
autodoc_mock_imports = ["rclpy", "rosidl_runtime_py", "std_msgs", "sensor_msgs", "geometry_msgs", "nav_msgs",
                        "torch", "torchvision"]

html_theme = "furo"
html_title = "embagents"

# Links: only internal ones are checked (external hosts are not reachable from CI).
linkcheck_ignore = [r"https?://.*", r"ws://.*", r"tcp://.*", r"ipc://.*"]

# Two modules define a class of the same short name (embagents.tools.graph.Node, embagents.manager.Node): a type
# hint naming it is ambiguous to Sphinx's resolver, which picks one and warns. Nothing else is hidden:
# a reference to nothing is not a warning unless nitpicky.
suppress_warnings = ["ref.python"]
