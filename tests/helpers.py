"""Small helpers shared by the tests."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator
from typing import Any


def wait_until(
    pred: Callable[[], Any],
    timeout: float = 10.0,
    what: str = "condition",
    *,
    interval: float = 0.01,
    poke: Callable[[], Any] | None = None,
) -> Any:
    """Call ``pred`` until it returns something truthy and return that; AssertionError naming ``what`` after ``timeout``.

    ``poke`` runs before each try (publish again, say, until a subscriber has it).

    >>> wait_until(lambda: 42)
    42
    """
    deadline = time.monotonic() + timeout
    while True:
        if poke is not None:
            poke()
        value = pred()
        if value:
            return value
        if time.monotonic() >= deadline:
            raise AssertionError(f"{what} not reached within {timeout} s (last: {value!r})")
        time.sleep(interval)


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port nobody listens on right now (the kernel's pick)."""
    import socket

    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def serve_http(handler: type) -> Iterator[str]:
    """A real HTTP server on a free local port, serving with ``handler`` on threads: yields its base URL."""
    import threading
    from http.server import ThreadingHTTPServer

    httpd = ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{httpd.server_address[1]}"
    finally:
        httpd.shutdown()
        httpd.server_close()
        thread.join(5)


#: The system's own ALSA config, which the test devices are added to.
ALSA_CONF = "/usr/share/alsa/alsa.conf"
_ASOUND = """
pcm.robotmic {{
    type file
    slave.pcm "null"
    file "/dev/null"
    infile "{dir}/mic.raw"
    format "raw"
}}
pcm.robotspeaker {{
    type file
    slave.pcm "null"
    file "{dir}/speaker.raw"
    format "raw"
}}
"""


def alsa_file_devices(folder: Any) -> str:
    """Define ALSA devices ``robotmic`` (captures ``folder/mic.raw``, 16-bit raw) and ``robotspeaker``
    (writes ``folder/speaker.raw``) on ALSA's file plugin; returns the ``ALSA_CONFIG_PATH`` that shows them.

    A sound card without one: PortAudio lists them as it lists real devices. Their slave is ALSA's
    ``null`` PCM, which does not pace (a device is as fast as it is read).
    """
    import os

    conf = os.path.join(str(folder), "asound.conf")
    with open(conf, "w") as f:
        f.write(_ASOUND.format(dir=folder))
    return f"{ALSA_CONF}:{conf}"  # the system's config, then ours


def skip_unless_portaudio() -> None:
    """Skip (the test, or the module when called at its top) unless sounddevice, its PortAudio library and
    ALSA's config are all there: the Microphone and Speaker run on them.

    Looks without importing sounddevice: it raises OSError (not ImportError, which ``importorskip``
    catches) when it cannot find its library, which it looks up as ``ctypes.util.find_library("portaudio")``.
    """
    import ctypes.util
    import importlib.util
    import os

    import pytest

    if importlib.util.find_spec("sounddevice") is None:
        pytest.skip("the Microphone and Speaker need sounddevice: pip install -e '.[speech]'", allow_module_level=True)
    if ctypes.util.find_library("portaudio") is None:
        pytest.skip("sounddevice's PortAudio library is missing: sudo apt install libportaudio2",
                    allow_module_level=True)
    if not os.path.isfile(ALSA_CONF):
        pytest.skip(f"ALSA's config {ALSA_CONF} is missing: sudo apt install libportaudio2 (it brings libasound2)",
                    allow_module_level=True)


def pyproject_extras() -> dict[str, list[str]]:
    """The extras of the checkout's pyproject.toml (not of whatever embagents is installed)."""
    import sys
    from pathlib import Path

    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover
        import tomli as tomllib
    pyproject = Path(__file__).parents[1] / "pyproject.toml"
    project = tomllib.loads(pyproject.read_text())["project"]
    return {"": list(project["dependencies"]), **project["optional-dependencies"]}


def _installed_closure(requirements: list[str]) -> set[str]:
    """The installed distributions ``requirements`` bring, with everything they depend on (normalized names).

    Markers other than ``extra`` count as true: a distribution too many here hides nothing that should be.
    """
    import re
    from importlib import metadata

    def name(req: str) -> str:
        return re.sub(r"[-_.]+", "-", re.match(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)", req)[1]).lower()  # type: ignore[index]

    seen: set[str] = set()
    todo = [name(r) for r in requirements]
    while todo:
        dist = todo.pop()
        if dist in seen:
            continue
        try:
            requires = metadata.requires(dist) or []
        except metadata.PackageNotFoundError:
            continue
        seen.add(dist)
        todo += [name(r) for r in requires if not re.search(r"\bextra\s*==", r)]
    return seen


def modules_outside_extras(extras: list[str]) -> set[str]:
    """Top-level modules that pyproject.toml's runtime extras install but ``extras`` (with the base
    dependencies) do not: what a user who installed only ``extras`` cannot import.
    """
    import re
    from importlib import metadata

    from embagents.extras import AGGREGATE_EXTRAS

    table = pyproject_extras()
    unknown = set(extras) - set(table)
    assert not unknown, f"no such extra in pyproject.toml: {sorted(unknown)}"

    def expand(names: list[str]) -> list[str]:  # embagents[a,b] inside an extra
        out: list[str] = []
        for n in names:
            for req in table[n]:
                inner = re.fullmatch(r"embagents\[([^\]]+)\]", req.strip())
                out += expand(inner[1].split(",")) if inner else [req]
        return out

    allowed = _installed_closure(expand(["", *extras]) + ["pip", "setuptools", "wheel"])  # a new venv's own
    runtime = [n for n in table if n and n not in AGGREGATE_EXTRAS]
    others = _installed_closure(expand(runtime)) - allowed
    hidden: set[str] = set()
    for module, providers in metadata.packages_distributions().items():
        dists = {re.sub(r"[-_.]+", "-", d).lower() for d in providers}
        if dists and dists <= others and module.isidentifier():
            hidden.add(module)
    return hidden


_HIDE = '''"""Written by tests/helpers.hide_modules: these top-level modules cannot be found, as if not installed."""
import sys
from importlib.machinery import PathFinder

_HIDDEN = frozenset({hidden!r})


class _Hiding(PathFinder):
    @classmethod
    def find_spec(cls, fullname, path=None, target=None):
        if fullname.partition(".")[0] in _HIDDEN:
            return None
        return PathFinder.find_spec(fullname, path, target)


sys.meta_path[:] = [_Hiding if f is PathFinder else f for f in sys.meta_path]
'''


def hide_modules(folder: Any, modules: Any, env: dict[str, str] | None = None) -> dict[str, str]:
    """An environment (``env``, default ``os.environ``) whose Python processes cannot find the top-level
    ``modules``, as if not installed: a ``sitecustomize`` in ``folder`` put first on ``PYTHONPATH``.
    Processes forked from them, and Python processes they start with this environment, cannot either.
    """
    import os

    env = dict(os.environ if env is None else env)
    os.makedirs(str(folder), exist_ok=True)
    with open(os.path.join(str(folder), "sitecustomize.py"), "w") as f:
        f.write(_HIDE.format(hidden=sorted(modules)))
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(folder), env.get("PYTHONPATH", "")) if p)
    return env
