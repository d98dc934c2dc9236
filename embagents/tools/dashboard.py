"""The dashboard: a page served by the root of ``embagents supervise --dashboard``, and its API.

On ``http://127.0.0.1:8420/?token=...`` (``--dashboard-host`` /
``--dashboard-port``; the token is new each run): the status table (what
``embagents status`` shows, live), per-topic rates, the latest image of
each image topic with the latest detections drawn, the latest text of each
text topic (a ``StreamingString`` stream joined), the supervisor's events,
and buttons to restart an actor or run a lifecycle transition. The same
data for other front ends:

- ``GET /api/state``: the state as JSON (``system``, ``run_id``, ``uptime``,
  ``rows``, ``topics``, ``texts``, ``images``, ``events``);
- ``GET /api/image?topic=NAME``: the latest frame of an image topic, as JPEG
  with the detections drawn (needs ``embagents[vision]`` for OpenCV);
- WebSocket ``/ws``: ``{"op": "state", ...}`` once a second; send
  ``{"op": "restart", "name": N}`` or ``{"op": "lifecycle", "name": N,
  "transition": "deactivate"}`` and get ``{"op": "result", "ok", ...}``.

Who may use it (:mod:`embagents.tools.webguard`): a request must name the
dashboard in its ``Host`` (``127.0.0.1``, ``localhost`` or the bound host,
with the port; else 421: a DNS-rebinding page names its own host), ``/ws``
and ``/api/*`` need the run's token (the ``token`` query parameter, an
``Authorization: Bearer`` header, or the ``HttpOnly; SameSite=Strict``
cookie that opening the printed URL sets; else 403), and a WebSocket
handshake from a page of another origin (``Origin: null`` included) is
refused (403) whatever it carries.

The server (the ``websockets`` package, HTTP and WebSocket on one port)
runs on its own thread of the root; its subscriptions are keep-latest, so
the page never slows the robot. A port already taken is refused with
:class:`DashboardError` naming it and the flag that moves it; the system
runs on without the dashboard.

Example::

    dash = Dashboard(sup, control, system, topics).start("127.0.0.1", 8420)
    print(dash.url)  # http://127.0.0.1:8420/?token=...
    ...
    dash.stop()
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import http.cookies
import json
import logging
import threading
import time
from importlib import resources
from typing import Any
from urllib.parse import parse_qs, urlsplit

from actors.errors import RemoteError
from actors.topics import Subscription
from embagents.components.imaging import annotate, image_rgb
from embagents.system import System
from embagents.tools.webguard import host_allowed, new_token, same_token
from supervisor import lifecycle

__all__ = ["DEFAULT_PORT", "Dashboard", "DashboardError"]

log = logging.getLogger("embagents.dashboard")
#: The dashboard's default port.
DEFAULT_PORT = 8420
#: Detections newer than this are drawn over an image.
_DETECTIONS_FRESH_S = 2.0
#: The most of one streamed text the dashboard keeps (its end).
_STREAM_CHARS = 4000


class DashboardError(RuntimeError):
    """The dashboard could not start (its port is taken, say)."""


class _Latest:
    """The latest message of each watched topic, and the supervisor's recent events (root IO thread writes)."""

    def __init__(self) -> None:
        self.texts: dict[str, str] = {}
        self.streams: dict[str, str] = {}  # topic -> the stream_id its text is assembled from
        self.images: dict[str, tuple[int, Any]] = {}  # topic -> (count, message)
        self.detections: dict[str, tuple[float, Any]] = {}  # topic -> (when, message)
        self.events: collections.deque[dict[str, Any]] = collections.deque(maxlen=30)

    def callback(self, topic: str, type_name: str) -> Any:
        def text(msg: Any) -> None:
            self.texts[topic] = str(getattr(msg, "data", msg))

        def chunk(msg: Any) -> None:  # a StreamingString: the chunks of one stream_id, joined (the last is often "")
            if self.streams.get(topic) != msg.stream_id:
                self.streams[topic], self.texts[topic] = msg.stream_id, ""
            self.texts[topic] = (self.texts[topic] + msg.data)[-_STREAM_CHARS:]

        def image(msg: Any) -> None:
            self.images[topic] = (self.images.get(topic, (0, None))[0] + 1, msg)

        def detections(msg: Any) -> None:
            self.detections[topic] = (time.monotonic(), msg)

        def event(msg: Any) -> None:
            self.events.appendleft(msg)

        return {"String": text, "StreamingString": chunk, "Image": image, "CompressedImage": image,
                "Detections": detections, "SupervisorEvent": event}.get(type_name)


_REASONS = {200: "OK", 303: "See Other", 403: "Forbidden", 404: "Not Found", 421: "Misdirected Request",
            503: "Service Unavailable"}


def _one_line(exc: BaseException) -> str:
    """An error as one line, type and message: not a remote traceback (it names paths of the robot's files)."""

    if isinstance(exc, RemoteError):
        return f"{exc.exc_type}: {(exc.remote_message.splitlines() or [''])[0]}"
    return f"{type(exc).__name__}: {(str(exc).splitlines() or [''])[0]}"


def _jpeg(msg: Any, detections: list[Any]) -> bytes:
    import cv2


    rgb = image_rgb(msg).copy()  # the frame may live in a ring the publisher reuses: copy it once
    for d in detections:
        rgb = annotate(rgb, d.boxes, d.labels, d.scores)
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 80])
    if not ok:
        raise ValueError("the frame did not encode as JPEG")
    return bytes(buf)


class Dashboard:
    """The dashboard of one run: ``start(host, port)``, ``state()``, ``stop()``."""

    def __init__(self, sup: Any, control: Any, system: System, topics: Any) -> None:
        self.sup, self.control, self.system, self.topics = sup, control, system, topics
        self.latest = _Latest()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._stop: asyncio.Event | None = None
        self._state: dict[str, Any] = {}
        self._lock = threading.Lock()
        self._subs: dict[str, Any] = {}  # topic -> the dashboard's own subscription (rates nobody else counts)
        self._seen: tuple[float, dict[str, int]] | None = None
        self.token = new_token()  # for /ws and /api/*: shown to whoever started the run, in `url`
        self.host, self.port = "127.0.0.1", 0

    # -- data ------------------------------------------------------------------
    def subscribe(self) -> None:
        """Watch the run's text, image and detection topics and its events (keep-latest)."""
        from embagents.tools.root import topic_rows  # lazy: a cycle

        asys = self.control.system
        for row in topic_rows(self.system, asys.run_dir):
            cb = self.latest.callback(row["name"], row["type"])
            if cb is not None:
                # Every chunk of a stream (it is assembled), the recent events; else the latest message.
                depth = {"SupervisorEvent": 30, "StreamingString": 256}.get(row["type"], 1)
                self._subs[row["name"]] = asys.rt.on_client(lambda n=row["name"], c=cb, q=depth: Subscription(
                    asys.rt, asys.loop, n, c, queue_size=q, keep="latest"))

    def state(self) -> dict[str, Any]:
        """The dashboard's data (``GET /api/state``): status rows, topic rates, texts, images, events."""
        with self._lock:  # one look at the actors at a time, however many clients ask
            rows = self.control.rows()
            images = {t: {"count": n, "url": f"/api/image?topic={t}&n={n}", "width": int(getattr(m, "width", 0) or 0),
                          "height": int(getattr(m, "height", 0) or 0)}
                      for t, (n, m) in list(self.latest.images.items())}  # list(): one atomic copy (IO thread writes)
            topics = self.topics.table(rows)
            self._own_rates(topics)
            self._state = {
                "system": self.control.name, "run_id": self.control.system.run_id,
                "uptime": round(time.monotonic() - self.control._t0, 1), "time": time.time(),
                "rows": [{k: r.get(k) for k in ("name", "kind", "status", "lifecycle", "pid", "restarts", "uptime",
                                                 "cpu_percent", "rss_mb", "mailbox", "rate", "drops")} for r in rows],
                "topics": topics, "texts": dict(self.latest.texts), "images": images,
                "events": [{k: v for k, v in e.items() if isinstance(v, (str, int, float, type(None)))}
                           for e in list(self.latest.events)],
            }
            return self._state

    def _own_rates(self, topics: list[dict[str, Any]]) -> None:
        """Fill in the rate of topics no actor subscribes to, from the dashboard's own counters."""
        now, counts = time.monotonic(), {t: s.received for t, s in self._subs.items()}
        then, before = self._seen or (now, {})
        for t in topics:
            n, n0 = counts.get(t["name"]), before.get(t["name"])
            if t["rate"] is None and n is not None and n0 is not None and now > then:
                t["rate"] = round((n - n0) / (now - then), 1)
        self._seen = (now, counts)

    def image(self, topic: str) -> bytes:
        found = self.latest.images.get(topic)
        if found is None:
            raise KeyError(f"no image on {topic!r} yet; image topics: {', '.join(self.latest.images) or 'none'}")
        now = time.monotonic()
        fresh = [d for when, d in list(self.latest.detections.values()) if now - when < _DETECTIONS_FRESH_S]
        return _jpeg(found[1], fresh)

    def act(self, req: dict[str, Any]) -> dict[str, Any]:
        """A button: ``restart`` or ``lifecycle`` (``transition``) on actor ``name``."""

        op, name = req.get("op"), req.get("name")
        if op == "restart":
            return {"op": "result", **self.control.handle({"cmd": "restart", "name": name})}
        if op == "lifecycle" and isinstance(name, str):
            try:
                state = lifecycle.transition(self.control.system, name, str(req.get("transition")))
            except Exception as exc:
                log.debug("lifecycle %s of %s failed: %s", req.get("transition"), name, exc)  # a remote traceback too
                return {"op": "result", "ok": False, "error": f"{name}: {_one_line(exc)}"}
            return {"op": "result", "ok": True, "name": name, "lifecycle": state}
        return {"op": "result", "ok": False, "error": f"unknown op {op!r}: restart or lifecycle"}

    # -- serving ---------------------------------------------------------------
    @property
    def url(self) -> str:
        """The page's address with the run's token: opening it sets the cookie that the page then uses."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/?token={self.token}"

    def start(self, host: str, port: int) -> Dashboard:
        """Serve on ``host:port`` from a thread of its own; DashboardError if it cannot."""
        started: collections.deque[BaseException | None] = collections.deque()
        ready = threading.Event()
        self.host = host  # before the first request: its Host is checked against it

        def main() -> None:
            loop = asyncio.new_event_loop()
            self._loop = loop
            try:
                loop.run_until_complete(self._serve(host, port, started, ready))
            except BaseException as exc:  # a bind error: told to start(), which raises it
                if not ready.is_set():
                    started.append(exc)
                    ready.set()
            finally:
                loop.close()

        self._thread = threading.Thread(target=main, name="embagents-dashboard", daemon=True)
        self._thread.start()
        ready.wait(10)
        error = started[0] if started else None
        if error is not None:
            raise DashboardError(f"the dashboard cannot listen on {host}:{port} ({error}); that port is taken or "
                                 "not this machine's: choose another with --dashboard-port PORT") from None
        self.subscribe()
        log.info("dashboard on http://%s:%d/", host, self.port)  # the log has no token: the URL is said on stderr
        return self

    async def _serve(self, host: str, port: int, started: Any, ready: threading.Event) -> None:
        from websockets.asyncio.server import serve

        self._stop = asyncio.Event()
        async with serve(self._client, host, port, process_request=self._http) as server:
            self.port = int(next(iter(server.sockets)).getsockname()[1])
            started.append(None)
            ready.set()
            await self._stop.wait()

    def _allowed(self, request: Any) -> str | None:
        """None if ``request`` may have ``/ws`` and ``/api/*``, else why not (with the fix)."""
        url = urlsplit(request.path)
        given = parse_qs(url.query).get("token", [None])[0]
        if given is None:
            auth = request.headers.get_all("Authorization")
            given = auth[0][7:].strip() if len(auth) == 1 and auth[0][:7].lower() == "bearer " else None
        if given is None:
            jar = http.cookies.SimpleCookie()
            with contextlib.suppress(http.cookies.CookieError):
                jar.load("; ".join(request.headers.get_all("Cookie")))
            given = jar[self._cookie].value if self._cookie in jar else None
        if given is None:
            return "this dashboard needs the token of its run: open the URL that `embagents supervise` printed " \
                   "(http://HOST:PORT/?token=...), or send ?token=, an Authorization: Bearer header or its cookie"
        if not same_token(given, self.token):
            return "wrong token: it changes each run; open the URL that this run's `embagents supervise` printed"
        return None

    @property
    def _cookie(self) -> str:
        return f"embagents_dashboard_{self.port}"  # cookies ignore the port: one per dashboard on the same host

    def _own_origin(self, origin: str) -> bool:
        url = urlsplit(origin)
        return url.scheme == "http" and host_allowed(url.netloc, self.host, self.port)

    def _http(self, connection: Any, request: Any) -> Any:
        from websockets.datastructures import Headers
        from websockets.http11 import Response

        def reply(status: int, body: bytes, ctype: str = "text/plain; charset=utf-8",
                  extra: tuple[tuple[str, str], ...] = ()) -> Response:
            headers = Headers([("Content-Type", ctype), ("Content-Length", str(len(body))), ("Cache-Control", "no-store"),
                               *extra])
            return Response(status, _REASONS.get(status, "Error"), headers, body)

        hosts = request.headers.get_all("Host")
        if len(hosts) != 1 or not host_allowed(hosts[0], self.host, self.port):
            names = " or ".join(f"{h}:{self.port}" for h in dict.fromkeys((self.host, "127.0.0.1", "localhost")))
            return reply(421, f"this dashboard answers to {names}, not to Host {', '.join(hosts) or '(none)'}: "
                              "open the URL that `embagents supervise` printed".encode())
        url = urlsplit(request.path)
        why = self._allowed(request)
        if url.path == "/ws":
            origins = request.headers.get_all("Origin")
            if origins and (len(origins) != 1 or not self._own_origin(origins[0])):
                return reply(403, f"a page of another origin ({', '.join(origins)}) may not use this dashboard: "
                                  f"open the dashboard's own page".encode())
            return reply(403, why.encode()) if why else None  # None: the WebSocket handshake goes on
        if url.path in ("/", "/index.html"):
            if why is None and "token" in parse_qs(url.query):  # the printed URL: keep the token in a cookie,
                return reply(303, b"", extra=(  # and take it out of the address bar and the history
                    ("Set-Cookie", f"{self._cookie}={self.token}; HttpOnly; SameSite=Strict; Path=/"), ("Location", "/")))
            if why is not None:
                return reply(403, why.encode())
            page = resources.files("embagents.tools").joinpath("dashboard.html").read_bytes()
            return reply(200, page, "text/html; charset=utf-8")
        if url.path.startswith("/api/") and why is not None:
            return reply(403, why.encode())
        if url.path == "/api/state":
            return reply(200, json.dumps(self.state(), default=str).encode(), "application/json")
        if url.path == "/api/image":
            topic = parse_qs(url.query).get("topic", [""])[0]
            try:
                return reply(200, self.image(topic), "image/jpeg")
            except KeyError as exc:
                return reply(404, str(exc).encode())
            except (ImportError, ValueError) as exc:  # no OpenCV, or a frame it cannot show
                return reply(503, f"cannot show {topic}: {exc} (pip install 'embagents[vision]')".encode())
        return reply(404, b"not found: try / or /api/state")

    async def _client(self, ws: Any) -> None:
        from websockets.exceptions import ConnectionClosed

        loop = asyncio.get_running_loop()

        async def push() -> None:
            while True:
                state = await loop.run_in_executor(None, self.state)
                await ws.send(json.dumps({"op": "state", **state}, default=str))
                await asyncio.sleep(1.0)

        pusher = asyncio.create_task(push())
        try:
            async for raw in ws:
                try:
                    req = json.loads(raw)
                    answer = await loop.run_in_executor(None, self.act, req if isinstance(req, dict) else {})
                except Exception as exc:  # a bad request is answered, the page goes on
                    log.debug("dashboard request %.200r failed", raw, exc_info=True)
                    answer = {"op": "result", "ok": False, "error": _one_line(exc)}
                await ws.send(json.dumps(answer, default=str))
        except ConnectionClosed as exc:  # a tab closed or a network gone: no close frame, nothing to do
            log.debug("dashboard client %s left: %s", ws.remote_address, exc)
        finally:
            pusher.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await pusher

    def stop(self) -> None:
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(stop.set)
        if self._thread is not None:
            self._thread.join(5)
