"""Which extra of embagents installs a module: the hint of an error about a missing optional module.

The extras are read from embagents' own installed metadata (pyproject.toml's
``[project.optional-dependencies]``), so this module holds only the import
names of the distributions whose import name differs from their PyPI name.

Example::

    >>> install_hint("sounddevice")  # doctest: +SKIP
    "pip install 'embagents[speech]'"
    >>> import_name("opencv-python-headless")
    'cv2'
"""

from __future__ import annotations

import functools
import re

__all__ = ["AGGREGATE_EXTRAS", "extras_of", "import_name", "install_hint"]

#: Extras that only gather others or serve development: never the one to name for a module.
AGGREGATE_EXTRAS = frozenset({"all", "local", "models", "tests"})

#: PyPI distribution (normalized) -> its import name, where the two differ beyond ``-`` and ``_``.
_IMPORT_NAMES = {
    "llama-cpp-python": "llama_cpp",
    "opencv-python-headless": "cv2",
    "opencv-python": "cv2",
    "scikit-image": "skimage",
    "urdfdom-py": "urdf_parser_py",
    "grpcio": "grpc",
    "protobuf": "google.protobuf",
    "foxglove-sdk": "foxglove",
    "huggingface-hub": "huggingface_hub",
    "ros-rclpy": "rclpy",
    "eclipse-zenoh": "zenoh",
    "ros-std-msgs": "std_msgs",
    "ros-sensor-msgs": "sensor_msgs",
    "ros-geometry-msgs": "geometry_msgs",
    "ros-nav-msgs": "nav_msgs",
    "ros-trajectory-msgs": "trajectory_msgs",
    "ros-std-srvs": "std_srvs",
    "ros-lifecycle-msgs": "lifecycle_msgs",
    "ros-action-msgs": "action_msgs",
    "ros-test-msgs": "test_msgs",
    "ros-rmw-fastrtps-cpp": "rmw_fastrtps_cpp",
}
_REQUIREMENT = re.compile(r"^\s*([A-Za-z0-9][A-Za-z0-9._-]*).*?extra\s*==\s*['\"]([^'\"]+)['\"]")


def import_name(distribution: str) -> str:
    """The name ``import`` takes for the PyPI ``distribution``."""
    dist = re.sub(r"[-_.]+", "-", distribution).lower()
    return _IMPORT_NAMES.get(dist, dist.replace("-", "_"))


@functools.lru_cache(maxsize=1)
def _module_extras() -> dict[str, tuple[str, ...]]:
    """Import name -> the extras that install it, in pyproject.toml's order; empty when embagents has no metadata."""
    from importlib import metadata

    try:
        requires = metadata.requires("embagents") or []
    except metadata.PackageNotFoundError:  # run from a checkout that was never pip-installed
        return {}
    found: dict[str, list[str]] = {}
    for line in requires:
        m = _REQUIREMENT.match(line)
        if m and m[2] not in AGGREGATE_EXTRAS and m[1].lower() != "embagents":
            extras = found.setdefault(import_name(m[1]), [])
            if m[2] not in extras:
                extras.append(m[2])
    return {name: tuple(extras) for name, extras in found.items()}


def extras_of(module: str) -> tuple[str, ...]:
    """The extras that install ``module`` (a dotted name: its longest known prefix counts); () if none does."""
    table = _module_extras()
    parts = module.split(".")
    for i in range(len(parts), 0, -1):
        extras = table.get(".".join(parts[:i]))
        if extras:
            return extras
    # google.protobuf is known by its full name; a missing namespace package reports only "google".
    return next((e for name, e in table.items() if name.split(".")[0] == module), ())


def install_hint(module: str) -> str:
    """What to run so that ``import module`` works: the extra that has it, else the module's own name."""
    extras = extras_of(module)
    if not extras:
        return f"pip install {module.split('.')[0]} (no extra of embagents installs it)"
    also = f" (also in: {', '.join(extras[1:])})" if len(extras) > 1 else ""
    return f"pip install 'embagents[{extras[0]}]'{also}"
