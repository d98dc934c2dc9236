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

Example::

    $ embagents view --port 8765
    serving 5 topics of system vision_demo to Foxglove at ws://127.0.0.1:8765 (Ctrl-C stops)
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from typing import Any

from actors import UnsafeFolder
from supervisor.client import ControlError

__all__ = ["FoxgloveView", "run", "view_arguments"]


def view_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", default="127.0.0.1", help="address to serve on (default: this machine only)")
    parser.add_argument("--port", type=int, default=8765, help="TCP port (default 8765, Foxglove's)")
    parser.add_argument("--duration", type=float, help="stop after this many seconds")
    parser.add_argument("--run", help="run id, system name or pid (default: the only live run)")
    parser.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the run to answer")


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

    from embagents.tools.mcap_codec import _stamp

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

    def __init__(self, seat: Any, rows: list[dict[str, Any]], host: str, port: int) -> None:
        import foxglove

        foxglove.set_log_level("WARN")
        try:
            self.server = foxglove.start_server(name="embagents", host=host, port=port)
        except Exception as exc:  # the SDK's own error for a taken or unusable address
            raise ValueError(f"cannot serve Foxglove on {host}:{port} ({exc}); is the port taken? "
                             "choose another with --port") from None
        self.url = f"ws://{host}:{self.server.port}"
        self.channels: list[Any] = []
        for r in rows:
            self._add(seat, foxglove, r)

    def _add(self, seat: Any, foxglove: Any, row: dict[str, Any]) -> None:
        from actors.codec import message_class
        from embagents.msgs import Detections
        from embagents.tools.mcap_codec import kind_of

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
        for ch in self.channels:
            ch.close()
        self.server.stop()


def run(args: argparse.Namespace) -> int:
    """Serve until Ctrl-C / SIGTERM / ``--duration``; 1 with a one-line error for bad input."""
    from embagents.tools.attach import Attached, run_topics

    try:
        found, rows = run_topics(args.run, args.timeout)
        with Attached(found) as seat:
            view = FoxgloveView(seat, rows, args.host, args.port)
            print(f"serving {len(rows)} topics of system {found['system']} to Foxglove at {view.url} (Ctrl-C stops)",
                  flush=True)
            try:
                seat.run(timeout=args.duration)
            finally:
                view.close()
    except (ControlError, UnsafeFolder, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0
