"""The dashboard (`embagents supervise --dashboard`) in a real headless Chromium, and its JSON API.

Chromium (Debian's package) loads the page; the test drives it over the DevTools protocol
(a WebSocket): it sees a value change live, clicks an actor's restart button with a real
mouse event, and sees the restart count go up. The screenshot is docs/dashboard.png
(written there when EMBAGENTS_DOCS_SCREENSHOT is set).
"""

from __future__ import annotations

import base64
import itertools
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import textwrap
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from websockets.sync.client import connect

from tests.embagents.tools.conftest import Run
from tests.helpers import free_port, wait_until

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


class Page:
    """One Chromium tab over the DevTools protocol."""

    def __init__(self, ws: Any) -> None:
        self.ws = ws
        self.ids = itertools.count(1)

    def call(self, method: str, **params: Any) -> dict[str, Any]:
        n = next(self.ids)
        self.ws.send(json.dumps({"id": n, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv(timeout=30))
            if msg.get("id") == n:
                assert "error" not in msg, msg
                return msg["result"]

    def js(self, expression: str) -> Any:
        return self.call("Runtime.evaluate", expression=expression, returnByValue=True)["result"].get("value")

    def click(self, selector: str) -> None:
        """A real left click (mouse pressed and released) at the middle of ``selector``."""
        box = self.js(f"JSON.stringify(document.querySelector({json.dumps(selector)}).getBoundingClientRect())")
        r = json.loads(box)
        x, y = r["x"] + r["width"] / 2, r["y"] + r["height"] / 2
        for kind in ("mousePressed", "mouseReleased"):
            self.call("Input.dispatchMouseEvent", type=kind, x=x, y=y, button="left", clickCount=1)


@pytest.fixture
def browser(live_run: Run, tmp_path: Path) -> Iterator[Page]:
    if CHROMIUM is None:
        pytest.skip("needs Debian's chromium (apt-get install chromium; .ci/run installs it)")
    port = free_port()
    url = f"http://127.0.0.1:{live_run.dashboard_port}/"
    proc = subprocess.Popen([CHROMIUM, "--headless=new", "--no-sandbox", "--disable-gpu", "--no-first-run",
                             f"--remote-debugging-port={port}", f"--user-data-dir={tmp_path / 'profile'}",
                             "--window-size=1280,900", url], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        def page_target() -> str | None:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=2) as r:
                    pages = [t for t in json.load(r) if t["type"] == "page" and t["url"].startswith(url)]
            except OSError:
                return None
            return pages[0]["webSocketDebuggerUrl"] if pages else None

        with connect(wait_until(page_target, 60, "Chromium's page", interval=0.2), max_size=None,
                     open_timeout=30) as ws:
            yield Page(ws)
    finally:
        os.killpg(proc.pid, signal.SIGTERM)  # chromium and its helper processes
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def test_page_is_live_and_restart_button_restarts(live_run: Run, browser: Page, tmp_path: Path) -> None:
    cell = 'document.querySelector(\'tr[data-name="talker"] .uptime\')?.textContent'
    first = wait_until(lambda: browser.js(cell), 30, "the status table")
    wait_until(lambda: browser.js(cell) not in (None, first), 30, "the uptime to change, live")
    restarts = 'document.querySelector(\'tr[data-name="shout"] .restarts\')?.textContent'
    before = int(browser.js(restarts))
    browser.click('tr[data-name="shout"] button.restart')
    wait_until(lambda: int(browser.js(restarts) or -1) == before + 1, 30, "the restart count to go up")
    assert live_run.status()["shout"]["restarts"] == before + 1
    wait_until(lambda: browser.js("document.querySelector('img[data-topic=\"camera/image\"]')?.naturalWidth") == 320,
               30, "the latest image shown")
    assert "hello" in browser.js("document.getElementById('texts').textContent")
    wait_until(lambda: browser.js("document.getElementById('events').textContent.includes('restarted')"), 30,
               "the restart among the supervisor events")
    shot = base64.b64decode(browser.call("Page.captureScreenshot", format="png")["data"])
    assert shot[:8] == b"\x89PNG\r\n\x1a\n"
    (tmp_path / "dashboard.png").write_bytes(shot)
    if os.environ.get("EMBAGENTS_DOCS_SCREENSHOT"):
        (Path(__file__).parents[3] / "docs" / "dashboard.png").write_bytes(shot)


def test_json_api_and_image(live_run: Run) -> None:
    base = f"http://127.0.0.1:{live_run.dashboard_port}"
    with urllib.request.urlopen(f"{base}/api/state", timeout=10) as r:
        state = json.load(r)
    assert state["system"] == "tools_test" and {r["name"] for r in state["rows"]} >= {"talker", "shout"}
    assert {t["name"] for t in state["topics"]} >= {"chatter", "camera/image"}
    with urllib.request.urlopen(f"{base}/api/image?topic=camera/image", timeout=10) as r:
        assert r.headers["Content-Type"] == "image/jpeg" and r.read(3) == b"\xff\xd8\xff"


def test_websocket_api_pushes_state_and_runs_lifecycle_transitions(live_run: Run) -> None:
    with connect(f"ws://127.0.0.1:{live_run.dashboard_port}/ws", open_timeout=30) as ws:
        assert json.loads(ws.recv(timeout=30))["op"] == "state"

        def act(**req: Any) -> dict[str, Any]:
            ws.send(json.dumps(req))
            while (msg := json.loads(ws.recv(timeout=30)))["op"] != "result":
                pass
            return msg

        assert act(op="lifecycle", name="shout", transition="deactivate") == {
            "op": "result", "ok": True, "name": "shout", "lifecycle": "inactive"}
        assert live_run.status()["shout"]["lifecycle"] == "inactive"
        assert act(op="lifecycle", name="shout", transition="activate")["lifecycle"] == "active"
        bad = act(op="lifecycle", name="shout", transition="explode")
        assert not bad["ok"] and "unknown transition 'explode'" in bad["error"]
        assert "no child named 'nobody'" in act(op="restart", name="nobody")["error"]


def test_a_taken_dashboard_port_says_which_and_the_system_runs_on(tmp_path: Path) -> None:
    path = tmp_path / "system.py"
    path.write_text(textwrap.dedent('''
        from embagents import Component, System
        system = System([Component(name="idle", trigger=None)], name="dash_port_test")
    '''))
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        proc = subprocess.Popen([sys.executable, "-m", "embagents.cli", "supervise", str(path), "--dashboard",
                                 "--dashboard-port", str(port)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True)
        try:
            assert proc.stdout is not None
            lines: list[str] = []
            wait_until(lambda: lines.append(proc.stdout.readline()) or "running (" in lines[-1], 90, "the system")
            said = "".join(lines)
            assert f"cannot listen on 127.0.0.1:{port}" in said and "--dashboard-port PORT" in said
            status = subprocess.run([sys.executable, "-m", "embagents.cli", "status", "--run", str(proc.pid)],
                                    capture_output=True, text=True, timeout=60)
            assert status.returncode == 0 and "idle" in status.stdout  # it runs on without the dashboard
        finally:
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(30) == 0
