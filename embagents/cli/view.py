"""``embagents view``: the live run's topics over the Foxglove WebSocket protocol.

A Foxglove server (``foxglove-sdk``) on ``ws://127.0.0.1:8765``: open
Foxglove, "Open connection", that address. Each topic is a channel with the
schema it has in recordings (:mod:`embagents.tools.mcap_codec`: images,
compressed images and audio in Foxglove's own schemas, the rest JSON);
detections also go out as ``foxglove.ImageAnnotations`` on
``<topic>/annotations`` (boxes and labels drawn over the image); the
supervisor's events on ``_supervisor.events``. Subscriptions are
keep-latest and the server drops for a slow client: watching never slows
the robot.

Who may watch: a browser lets any page open a WebSocket to 127.0.0.1, and
says which page in the handshake's ``Origin``. The SDK's server listens on
a random loopback address and port of its own (a page cannot scan 127/8
for it), behind a front on ``--host:--port`` that reads
each handshake first: one without ``Origin`` (the desktop app, a program),
from an allowed origin (``https://app.foxglove.dev``; ``--allow-origin``
adds one) or with the run's token (``?token=``) goes through; any other is
refused with 403.

Example::

    $ embagents view --port 8765
    serving 5 topics of system vision_demo to Foxglove at ws://127.0.0.1:8765 (Ctrl-C stops)
    pages of origins other than https://app.foxglove.dev: ws://127.0.0.1:8765/?token=...
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import contextlib
import secrets
import sys
import threading
import time
from collections.abc import Callable
from typing import Any
from urllib.parse import parse_qs, urlsplit

from actors import UnsafeFolder
from actors.codec import message_class
from embagents.cli.control import run_arguments
from embagents.msgs import Detections
from embagents.tools.attach import Attached, run_topics
from embagents.tools.mcap_codec import _stamp, kind_of
from embagents.tools.webguard import exposed_warning, new_token, same_token
from supervisor.client import ControlError

__all__ = ["DEFAULT_ORIGINS", "FoxgloveView", "run", "arguments"]

#: Browser origins allowed without the token: Foxglove's web app.
DEFAULT_ORIGINS = ("https://app.foxglove.dev",)


def arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", default="127.0.0.1", help="address to serve on (default: this machine only)")
    parser.add_argument("--port", type=int, default=8765, help="TCP port (default 8765, Foxglove's)")
    parser.add_argument("--allow-origin", action="append", default=[], metavar="ORIGIN",
                        help="also let pages of this origin connect (e.g. http://localhost:8080; "
                             f"allowed: {', '.join(DEFAULT_ORIGINS)}); repeat for more")
    parser.add_argument("--duration", type=float, help="stop after this many seconds")
    run_arguments(parser)


def _annotations(det: Any) -> bytes:
    """Detections as ``foxglove.ImageAnnotations``: a box outline and a label each."""
    from foxglove.messages import (
        Color,
        ImageAnnotations,
        Point2,
        PointsAnnotation,
        PointsAnnotationType,
        TextAnnotation,
    )


    ts, green = _stamp(det.stamp), Color(r=0.1, g=0.9, b=0.2, a=1.0)
    boxes, texts = [], []
    for (x1, y1, x2, y2), label, score in zip(det.boxes.tolist(), det.labels, det.scores.tolist(), strict=False):
        corners = [Point2(x=x1, y=y1), Point2(x=x2, y=y1), Point2(x=x2, y=y2), Point2(x=x1, y=y2)]
        boxes.append(PointsAnnotation(timestamp=ts, type=PointsAnnotationType.LineLoop, points=corners,
                                      outline_color=green, thickness=2.0))
        texts.append(TextAnnotation(timestamp=ts, position=Point2(x=x1, y=max(y1 - 4, 0)), text=f"{label} {score:.2f}",
                                    font_size=14.0, text_color=green))
    return ImageAnnotations(points=boxes, texts=texts).encode()


class FoxgloveView:
    """A Foxglove WebSocket server fed by keep-latest subscriptions of ``seat`` (an Attached)."""

    def __init__(self, seat: Any, rows: list[dict[str, Any]], host: str, port: int,
                 origins: tuple[str, ...] = DEFAULT_ORIGINS) -> None:
        import foxglove

        foxglove.set_log_level("WARN")
        # On a loopback address and port of its own: the front below is the way in. A random address
        # of 127/8 (Linux answers on all of it) keeps a page from finding it by scanning ports.
        inner = f"127.{secrets.randbelow(254) + 1}.{secrets.randbelow(256)}.{secrets.randbelow(254) + 1}"
        try:
            try:
                self.server = foxglove.start_server(name="embagents", host=inner, port=0)
            except Exception:  # a system with 127.0.0.1 alone (macOS)
                inner = "127.0.0.1"
                self.server = foxglove.start_server(name="embagents", host=inner, port=0)
        except Exception as exc:  # the SDK's own error
            raise ValueError(f"cannot start the Foxglove server ({exc})") from None
        try:
            self.front = _Front(host, port, (inner, self.server.port), origins)
        except BaseException:
            self.server.stop()
            raise
        where = f"[{host}]" if ":" in host else host
        self.url = f"ws://{where}:{self.front.port}"
        self.token_url = f"{self.url}/?token={self.front.token}"
        self.channels: list[Any] = []
        for r in rows:
            self._add(seat, foxglove, r)

    def _add(self, seat: Any, foxglove: Any, row: dict[str, Any]) -> None:
        cls = message_class(row["wire"]) if row["wire"] else None
        kind = kind_of(cls)
        ch = foxglove.Channel(row["name"], schema=foxglove.Schema(name=kind.schema_name, encoding=kind.schema_encoding,
                                                                  data=kind.schema_data),
                              message_encoding=kind.message_encoding)
        self.channels.append(ch)
        sends: list[Callable[[Any], None]] = [lambda msg: ch.log(kind.encode(msg), log_time=time.time_ns())]
        if cls is Detections:
            from foxglove.messages import ImageAnnotations

            schema = ImageAnnotations.get_schema()
            ann = foxglove.Channel(f"{row['name']}/annotations", schema=schema, message_encoding="protobuf")
            self.channels.append(ann)
            sends.append(lambda msg: ann.log(_annotations(msg), log_time=time.time_ns()))

        def forward(msg: Any) -> None:
            for send in sends:
                send(msg)

        seat.subscribe(row["name"], forward)

    def close(self) -> None:
        self.front.close()
        for ch in self.channels:
            ch.close()
        self.server.stop()


class _Front:
    """The view's public port: reads each WebSocket handshake, refuses a page of a foreign origin (403),
    and passes the rest byte for byte to the SDK's server on ``inner`` (its backpressure stays)."""

    def __init__(self, host: str, port: int, inner: tuple[str, int], origins: tuple[str, ...]) -> None:
        self.host, self.inner, self.origins = host, inner, {o.rstrip("/") for o in origins}
        self.token = new_token()
        self.port, self._asked = 0, port
        self._refused: set[str] = set()
        self._clients: set[asyncio.Transport] = set()
        self._loop = asyncio.new_event_loop()
        self._stop = asyncio.Event()
        started: collections.deque[BaseException | None] = collections.deque()
        ready = threading.Event()
        self._thread = threading.Thread(target=self._main, args=(started, ready), name="embagents-view", daemon=True)
        self._thread.start()
        ready.wait(10)
        error = started[0] if started else None
        if error is not None:
            self._thread.join(5)
            raise ValueError(f"cannot serve Foxglove on {host}:{port} ({error}); is the port taken? "
                             "choose another with --port")

    def _main(self, started: collections.deque[BaseException | None], ready: threading.Event) -> None:
        async def serve() -> None:
            server = await asyncio.get_running_loop().create_server(lambda: _Client(self), self.host, self._asked)
            self.port = int(server.sockets[0].getsockname()[1])
            started.append(None)
            ready.set()
            async with server:
                await self._stop.wait()
                for client in list(self._clients):  # the clients' connections end with the view
                    client.close()
                await asyncio.sleep(0.1)  # their closes (and their inner connections') run

        try:
            self._loop.run_until_complete(serve())
        except BaseException as exc:  # a bind error: told to __init__, which raises it
            if not ready.is_set():
                started.append(exc)
                ready.set()
        finally:
            self._loop.close()

    def refusal(self, origins: list[str], target: str) -> str | None:
        """None if a handshake with these ``Origin`` headers for ``target`` may go on, else why not."""
        if not origins:
            return None  # not a browser page (browsers always send Origin): the desktop app, a program
        if len(origins) == 1 and origins[0].rstrip("/") in self.origins:
            return None
        if same_token(parse_qs(urlsplit(target).query).get("token", [None])[0], self.token):
            return None
        return (f"a page of origin {', '.join(origins)} may not watch this run: allow it with "
                "`embagents view --allow-origin ORIGIN`, or connect to the ?token= URL that `embagents view` printed")

    def answer(self, head: bytes) -> tuple[bytes | None, bytes]:
        """``(request to pass on, b"")`` for a handshake that may go on, else ``(None, the 403 response)``."""
        lines = head.decode("latin-1").split("\r\n")
        request = lines[0].split(" ")
        target = request[1] if len(request) == 3 else "/"
        origins = [v.strip() for k, _, v in (line.partition(":") for line in lines[1:]) if k.strip().lower() == "origin"]
        why = self.refusal(origins, target)
        if why is None:
            lines[0] = f"{request[0]} {urlsplit(target).path or '/'} {request[-1]}"  # the token stays here
            return "\r\n".join(lines).encode("latin-1"), b""
        if origins[0] not in self._refused:  # said once per origin: a page may retry without end
            self._refused.add(origins[0])
            print(f"embagents view: refused {why}", file=sys.stderr, flush=True)
        body = why.encode()
        return None, (b"HTTP/1.1 403 Forbidden\r\nContent-Type: text/plain; charset=utf-8\r\n"
                      b"Content-Length: %d\r\nConnection: close\r\n\r\n%s" % (len(body), body))

    def close(self) -> None:
        with contextlib.suppress(RuntimeError):  # already closed
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(5)


class _Client(asyncio.Protocol):
    """One connection to the front: its handshake is read and judged, then bytes go both ways as they come.

    A protocol rather than streams: no copy through a reader's buffer, and flow control passes
    straight through (a slow client pauses the reads from the SDK's server, which then drops for it).
    """

    def __init__(self, front: _Front) -> None:
        self.front, self.head = front, bytearray()
        self.transport: asyncio.Transport | None = None
        self.inner: asyncio.Transport | None = None
        self.early: bytearray | None = None  # bytes after the handshake, before the inner connection is up
        self.closed = False

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        transport.set_write_buffer_limits(high=1 << 20)
        self.front._clients.add(transport)
        self.timer = asyncio.get_running_loop().call_later(10, self._slow)

    def _slow(self) -> None:
        if self.early is None and self.transport is not None:
            self.transport.close()  # no whole request in 10 s

    def data_received(self, data: bytes) -> None:
        if self.inner is not None:
            self.inner.write(data)
        elif self.early is not None:
            self.early += data
        else:
            self.head += data
            end = self.head.find(b"\r\n\r\n")
            if end < 0:
                if len(self.head) > 1 << 16 and self.transport is not None:
                    self.transport.close()  # no HTTP request has a head this long
                return
            self.timer.cancel()
            passed, refusal = self.front.answer(bytes(self.head[:end + 4]))
            assert self.transport is not None
            if passed is None:
                self.transport.write(refusal)
                self.transport.close()
                return
            self.early = bytearray(passed + self.head[end + 4:])
            self.transport.pause_reading()
            self.connecting = asyncio.ensure_future(self._connect())  # kept: the loop holds tasks weakly

    async def _connect(self) -> None:
        assert self.transport is not None and self.early is not None
        client = self.transport
        try:
            inner, _ = await asyncio.get_running_loop().create_connection(lambda: _Inner(client), *self.front.inner)
        except OSError:
            client.close()
            return
        if self.closed:
            inner.close()
            return
        inner.write(bytes(self.early))
        self.inner = inner
        client.resume_reading()

    def pause_writing(self) -> None:  # the client reads slower than the SDK's server sends
        if self.inner is not None:
            self.inner.pause_reading()

    def resume_writing(self) -> None:
        if self.inner is not None:
            self.inner.resume_reading()

    def connection_lost(self, exc: Exception | None) -> None:
        self.closed = True
        self.timer.cancel()
        if self.transport is not None:
            self.front._clients.discard(self.transport)
        if self.inner is not None:
            self.inner.close()


class _Inner(asyncio.Protocol):
    """The front's connection to the SDK's server, for one client."""

    def __init__(self, client: asyncio.Transport) -> None:
        self.client = client

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        transport.set_write_buffer_limits(high=1 << 20)

    def data_received(self, data: bytes) -> None:
        self.client.write(data)

    def pause_writing(self) -> None:  # the SDK's server reads slower than the client sends
        self.client.pause_reading()

    def resume_writing(self) -> None:
        self.client.resume_reading()

    def connection_lost(self, exc: Exception | None) -> None:
        self.client.close()


def run(args: argparse.Namespace) -> int:
    """Serve until Ctrl-C / SIGTERM / ``--duration``; 1 with a one-line error for bad input."""

    try:
        for origin in args.allow_origin:
            url = urlsplit(origin)
            if url.scheme not in ("http", "https") or not url.netloc or url.path not in ("", "/") or url.query:
                raise ValueError(f"--allow-origin {origin!r} is not an origin: give scheme://host[:port], "
                                 "e.g. http://localhost:8080")
        found, rows = run_topics(args.run, args.timeout)
        with Attached(found) as seat:
            origins = (*DEFAULT_ORIGINS, *args.allow_origin)
            view = FoxgloveView(seat, rows, args.host, args.port, origins)
            print(f"serving {len(rows)} topics of system {found['system']} to Foxglove at {view.url} (Ctrl-C stops)",
                  flush=True)
            print(f"pages of origins other than {', '.join(origins)}: {view.token_url}", flush=True)
            warning = exposed_warning("embagents view", args.host, "--host", "any program that reaches it sees "
                                      "every topic, camera included (only browser pages are held to origins)")
            if warning:
                print(warning, file=sys.stderr, flush=True)
            try:
                seat.run(timeout=args.duration)
            finally:
                view.close()
    except (ControlError, UnsafeFolder, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0
