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
