"""The dashboard (`embagents supervise --dashboard`) in a real headless Chromium, and its JSON API.

Chromium (Debian's package) loads the page; the test drives it over the DevTools protocol
(a WebSocket): it sees a value change live, clicks an actor's restart button with a real
mouse event, and sees the restart count go up. The screenshot is docs/dashboard.png
(written there when EMBAGENTS_DOCS_SCREENSHOT is set).
"""

from __future__ import annotations

import base64
import http.client
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
from urllib.parse import parse_qs, urlsplit

import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from tests.embagents.fixtures.live_run import Run, dashboard_url
from tests.helpers import free_port, wait_until

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
#: The headers of a WebSocket handshake, for a raw HTTP client.
UPGRADE = {"Upgrade": "websocket", "Connection": "Upgrade", "Sec-WebSocket-Version": "13",
           "Sec-WebSocket-Key": base64.b64encode(b"0123456789abcdef").decode()}


def _token(run: Run) -> str:
    return parse_qs(urlsplit(run.dashboard_url).query)["token"][0]


def _get(port: int, path: str, headers: dict[str, str] | None = None) -> tuple[int, http.client.HTTPResponse, bytes]:
    """``GET path`` with exactly these headers (a ``Host`` given here replaces the real one)."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    try:
        conn.request("GET", path, headers=headers or {})
        r = conn.getresponse()
        return r.status, r, r.read()
    finally:
        conn.close()


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
    url = f"http://127.0.0.1:{live_run.dashboard_port}/"  # where the printed URL (with the token) leads
    proc = subprocess.Popen([CHROMIUM, "--headless=new", "--no-sandbox", "--disable-gpu", "--no-first-run",
                             f"--remote-debugging-port={port}", f"--user-data-dir={tmp_path / 'profile'}",
                             "--window-size=1280,900", live_run.dashboard_url], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        def page_target() -> str | None:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=2) as r:
                    pages = [t for t in json.load(r) if t["type"] == "page" and t["url"] == url]
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
    base, token = f"http://127.0.0.1:{live_run.dashboard_port}", _token(live_run)
    with urllib.request.urlopen(f"{base}/api/state?token={token}", timeout=10) as r:
        state = json.load(r)
    assert state["system"] == "tools_test" and {r["name"] for r in state["rows"]} >= {"talker", "shout"}
    assert {t["name"] for t in state["topics"]} >= {"chatter", "camera/image"}
    image = urllib.request.Request(f"{base}/api/image?topic=camera/image", headers={"Authorization": f"Bearer {token}"})
    with urllib.request.urlopen(image, timeout=10) as r:
        assert r.headers["Content-Type"] == "image/jpeg" and r.read(3) == b"\xff\xd8\xff"


def test_websocket_api_pushes_state_and_runs_lifecycle_transitions(live_run: Run) -> None:
    with connect(f"ws://127.0.0.1:{live_run.dashboard_port}/ws?token={_token(live_run)}", open_timeout=30) as ws:
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
        assert "\n" not in bad["error"] and "traceback" not in bad["error"] and ".py" not in bad["error"]  # one line
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


@pytest.mark.parametrize("origin", ["http://evil.example", "null", "http://127.0.0.1:1"])
def test_a_page_of_another_origin_is_refused_on_the_websocket(live_run: Run, origin: str) -> None:
    port, token = live_run.dashboard_port, _token(live_run)
    with pytest.raises(InvalidStatus) as refused:  # the token does not help a foreign page
        connect(f"ws://127.0.0.1:{port}/ws?token={token}", origin=origin, open_timeout=30)  # type: ignore[arg-type]
    assert refused.value.response.status_code == 403
    assert b"another origin" in refused.value.response.body
    with connect(f"ws://127.0.0.1:{port}/ws?token={token}", origin=f"http://localhost:{port}",  # type: ignore[arg-type]
                 open_timeout=30) as ws:  # its own page goes through
        assert json.loads(ws.recv(timeout=30))["op"] == "state"


def test_a_request_naming_another_host_is_refused(live_run: Run) -> None:
    port, token = live_run.dashboard_port, _token(live_run)
    for path, extra in [("/api/state", {}), ("/api/image?topic=camera/image&", {}), ("/ws", UPGRADE), ("/", {})]:
        where = f"{path}{'' if path.endswith('&') else '?'}token={token}"
        status, _r, body = _get(port, where, {"Host": f"evil.example:{port}", **extra})  # a DNS rebinding
        assert status == 421 and f"127.0.0.1:{port}".encode() in body, (path, status, body)
        assert _get(port, where, {"Host": f"127.0.0.1:{port + 1}", **extra})[0] == 421  # another port
    assert _get(port, f"/api/state?token={token}", {"Host": f"localhost:{port}"})[0] == 200


def test_without_the_token_or_with_a_wrong_one_is_refused(live_run: Run) -> None:
    port = live_run.dashboard_port
    for path, headers in [("/api/state", {}), ("/api/state?token=wrong", {}), ("/api/image?topic=camera/image", {}),
                          ("/api/state", {"Cookie": f"embagents_dashboard_{port}=wrong"}),
                          ("/api/state", {"Authorization": "Bearer wrong"}), ("/ws", UPGRADE),
                          ("/ws?token=wrong", UPGRADE), ("/", {})]:
        status, _r, body = _get(port, path, {"Host": f"127.0.0.1:{port}", **headers})
        assert status == 403 and b"printed" in body, (path, headers, status, body)
    with pytest.raises(InvalidStatus) as refused:
        connect(f"ws://127.0.0.1:{port}/ws", open_timeout=30)
    assert refused.value.response.status_code == 403


def test_the_printed_url_keeps_its_token_in_a_cookie_that_opens_the_websocket(live_run: Run) -> None:
    port, url = live_run.dashboard_port, urlsplit(live_run.dashboard_url)
    assert url.netloc == f"127.0.0.1:{port}" and url.path == "/"
    status, r, _body = _get(port, f"/?{url.query}", {"Host": url.netloc})
    cookie = r.getheader("Set-Cookie") or ""
    assert status == 303 and r.getheader("Location") == "/"  # the token leaves the address bar
    assert "HttpOnly" in cookie and "SameSite=Strict" in cookie
    jar = {"Cookie": cookie.split(";")[0]}
    status, _r, page = _get(port, "/", {"Host": url.netloc, **jar})
    assert status == 200 and b"<title>embagents dashboard</title>" in page
    assert _get(port, "/api/image?topic=camera/image", {"Host": url.netloc, **jar})[0] == 200
    with connect(f"ws://127.0.0.1:{port}/ws", origin=f"http://127.0.0.1:{port}",  # type: ignore[arg-type]
                 additional_headers=jar, open_timeout=30) as ws:
        assert json.loads(ws.recv(timeout=30))["op"] == "state"


STREAMER = textwrap.dedent('''
    from embagents import Component, StreamingString, System, Topic


    class Streamer(Component):
        """Streams "hello streamed world" in three chunks and an empty last one, twice a second."""

        def _execution_step(self, **_):
            self.n = getattr(self, "n", 0) + 1
            for part in ("hello", " streamed", " world"):
                self.publish("answer", StreamingString(data=part, stream_id=f"s{self.n}"))
            self.publish("answer", StreamingString(data="", done=True, stream_id=f"s{self.n}"))


    system = System([Streamer(name="streamer", outputs=[Topic("answer", StreamingString)], trigger=2.0)],
                    name="dash_stream_test")
''')


def test_on_every_address_it_warns_shows_streams_whole_and_a_vanished_client_is_no_error(tmp_path: Path) -> None:
    path, log = tmp_path / "system.py", tmp_path / "root.log"
    path.write_text(STREAMER)
    port = free_port()
    with open(log, "wb") as out:
        proc = subprocess.Popen([sys.executable, "-m", "embagents.cli", "supervise", str(path), "-v", "--dashboard",
                                 "--dashboard-host", "0.0.0.0", "--dashboard-port", str(port)],
                                stdout=out, stderr=subprocess.STDOUT)
    try:
        wait_until(lambda: "?token=" in log.read_text(errors="replace"), 90, "the dashboard")
        said = log.read_text(errors="replace")
        assert "warning: the dashboard listens on 0.0.0.0" in said and "--dashboard-host 127.0.0.1" in said
        token = parse_qs(urlsplit(dashboard_url(log)).query)["token"][0]

        def text() -> str | None:  # an IP address is no DNS rebinding: on 0.0.0.0 it is let in
            status, _r, body = _get(port, f"/api/state?token={token}", {"Host": f"127.0.0.2:{port}"})
            assert status == 200, body
            return json.loads(body)["texts"].get("answer")

        wait_until(lambda: text() == "hello streamed world", 60, "the whole stream as the latest text")

        with socket.create_connection(("127.0.0.1", port), timeout=30) as raw:  # a client that vanishes
            raw.sendall((f"GET /ws?token={token} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
                         + "".join(f"{k}: {v}\r\n" for k, v in UPGRADE.items()) + "\r\n").encode())
            assert raw.recv(4096).startswith(b"HTTP/1.1 101")
            raw.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")  # RST
        wait_until(lambda: "dashboard client" in log.read_text(errors="replace"), 30, "the client's leaving, logged")
        said = log.read_text(errors="replace")
        assert "connection handler failed" not in said and "Traceback" not in said, said[-3000:]
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 0
