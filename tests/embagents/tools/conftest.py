"""A live `embagents supervise` run shared by the tools tests (started once: it costs seconds)."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.helpers import free_port, wait_until

SYSTEM = '''
import logging

import numpy as np
from embagents import Component, Detections, Image, String, System, Topic

chatter = Topic("chatter", String, keep="all", queue_size=50)
image = Topic("camera/image", Image)
dets = Topic("dets", Detections)
loud = Topic("loud", String)
log = logging.getLogger("demo")


class Talker(Component):
    """Says "hello N" at 20 Hz with a small image and a detection."""

    def _execution_step(self, **_):
        self.n = getattr(self, "n", 0) + 1
        self.publish("chatter", String(data=f"hello {self.n}"))
        h, w = np.indices((240, 320))
        frame = np.stack([(w + self.n) % 256, h, 255 - h], axis=-1).astype(np.uint8)  # a gradient that moves
        self.publish("camera/image", Image(data=frame, stamp=float(self.n)))
        self.publish("dets", Detections(boxes=[[100, 60, 220, 200]], labels=["cup"], scores=[0.9],
                                        image_width=320, image_height=240))


class Shout(Component):
    """Upper-cases chatter onto loud; logs what it heard when it is not a "hello"."""

    def _execution_step(self, **inputs):
        text = inputs["chatter"].data
        if not text.startswith("hello"):
            log.info("heard %s", text)
        self.publish("loud", String(data=text.upper()))


system = System([Talker(name="talker", outputs=[chatter, image, dets], trigger=20.0),
                 Shout(name="shout", inputs=[chatter], outputs=[loud], trigger=chatter)], name="tools_test")
'''


def dashboard_url(log: Path) -> str:
    """The ``http://...?token=...`` URL that an `embagents supervise --dashboard` said in ``log``."""
    said = re.search(r"dashboard on (http://\S+/\?token=\S+)", log.read_text(errors="replace"))
    assert said is not None, f"no dashboard line in {log}"
    return said.group(1)


class Run:
    """The live run: ``cli(...)`` runs an `embagents` command against it."""

    def __init__(self, proc: subprocess.Popen[bytes], folder: Path, dashboard_port: int) -> None:
        self.proc, self.folder, self.dashboard_port = proc, folder, dashboard_port
        self.id = str(proc.pid)

    @property
    def dashboard_url(self) -> str:
        """The URL `embagents supervise` printed for the dashboard, token included."""
        return dashboard_url(self.folder / "root.log")

    def cli(self, *args: str, timeout: float = 60, stdin: str | None = None) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "embagents.cli", *args, "--run", self.id], input=stdin,
                              capture_output=True, text=True, timeout=timeout)

    def popen(self, *args: str) -> subprocess.Popen[str]:
        return subprocess.Popen([sys.executable, "-m", "embagents.cli", *args, "--run", self.id],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def status(self) -> dict[str, dict[str, Any]]:
        out = self.cli("status", "--json")
        assert out.returncode == 0, out.stderr
        return {r["name"]: r for r in json.loads(out.stdout)["rows"]}


@pytest.fixture(scope="session")
def live_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Run]:
    folder = tmp_path_factory.mktemp("tools_run")
    path = folder / "system.py"
    path.write_text(textwrap.dedent(SYSTEM))
    port = free_port()
    with open(folder / "root.log", "wb") as out:
        proc = subprocess.Popen([sys.executable, "-m", "embagents.cli", "supervise", str(path), "--dashboard",
                                 "--dashboard-port", str(port)], stdout=out, stderr=subprocess.STDOUT, env={**os.environ})
    run = Run(proc, folder, port)
    try:
        wait_until(lambda: run.cli("topic", "list").returncode == 0, 90, "the tools test run to answer",
                   interval=0.5)
        yield run
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
