"""Vision through the runtime: ``vision_pipeline`` and ``model_actor_batching``.

Both run the real parts: a detector model actor (MTCNN's ONNX files on
onnxruntime, in its own process) and the real :class:`~embagents.components.Vision`
component hosted in actor processes.

- ``vision_pipeline``: a 1080p RGB frame published by a camera-like publisher
  (this process), through the Vision component (a second process) and its model
  actor (a third), to a Detections subscriber (a fourth); latency from the
  frame's stamp to the subscriber's receipt. Baseline: the same detector
  (same files, same settings) called in this process on the same frame.
  ``ratio`` = runtime p50 / in-process p50; ``fps`` = frames per second through
  the runtime, one frame in flight.
- ``model_actor_batching``: four Vision components sharing one model actor,
  each stepping as fast as it is answered, against one component alone.
  ``ratio`` = frames per second served, four / one. The detector is a
  YOLOv8-layout conv net that takes batches (:mod:`embagents.bench.yolo_like`);
  MTCNN's per-image pyramid does not batch, and on two busy cores its four
  clients only share the same compute (about 1.0).
"""

from __future__ import annotations

import os
import queue
import statistics
import tempfile
import time
from functools import partial
from typing import Any

import numpy as np

import embagents.msgs  # noqa: F401 - registers the message types this case decodes
from actors import Actor, ActorSystem
from actors.topics import Publisher, Subscription
from embagents.bench.registry import Baseline, BenchOptions, case
from embagents.bench.yolo_like import write_yolo_like
from embagents.components import Vision
from embagents.models import LocalModelClient
from embagents.models.actor import ModelActor
from embagents.models.files.hub import mtcnn_dir
from embagents.msgs import Detections, Image
from embagents.topic import Topic

__all__ = ["DetectionSink", "SteppingVision"]  # actor classes the fork server imports by name

MODEL = "bench_faces"
OPTIONS = {"family": "mtcnn", "threshold": 0.9}


def _frame(width: int, height: int) -> np.ndarray:
    """The astronaut photo (a face) resized to ``width`` x ``height``, RGB."""
    import cv2
    from skimage import data

    return np.ascontiguousarray(cv2.resize(data.astronaut(), (width, height), interpolation=cv2.INTER_LINEAR))


class SteppingVision(Actor):
    """The Vision component, fed by a topic (``topic``) or stepped on request with its own frame."""

    def __init__(self, topic: str | None, width: int = 640, height: int = 480) -> None:
        self.topic, self.size = topic, (width, height)

    def on_start(self) -> None:
        inp = Topic(self.topic or "bench_unused", Image)
        self.vision = Vision(name=self.name, inputs=[inp], outputs=[Topic("bench_detections", Detections)],
                             model_client=LocalModelClient(MODEL))
        self.vision.attach(lambda topic, msg: self.context.publish(topic, msg))
        self.image = Image(data=_frame(*self.size), frame_id=self.name)
        if self.topic:
            self.context.subscribe(self.topic, partial(self._on_frame, self.topic), queue_size=2)

    def _on_frame(self, topic: str, msg: Any) -> None:
        if self.vision.on_message(topic, msg):
            self.vision.execute()

    def on_receive(self, message: Any) -> Any:
        """``["run", seconds]``: step as fast as answered for that long; returns the steps done."""
        _, seconds = message
        end, steps = time.monotonic() + float(seconds), 0
        while time.monotonic() < end:
            self.vision.on_message("bench_unused", self.image)
            steps += int(self.vision.execute())
        return steps


class DetectionSink(Actor):
    """Publishes, for each Detections that arrives, its latency from its frame's stamp."""

    def on_start(self) -> None:
        self.context.subscribe("bench_detections", self._on_det, queue_size=100, keep="all")

    def _on_det(self, det: Any) -> None:
        self.context.publish("bench_latency", time.monotonic() - det.stamp)


_BASELINE = """
import sys, time
from embagents.models.backends.detectors import make_detector
from embagents.bench.cases_vision import OPTIONS, _frame
from embagents.models.files.hub import mtcnn_dir
det, frame = make_detector(mtcnn_dir(), **OPTIONS), _frame(1920, 1080)
for _ in sys.stdin:
    t0 = time.monotonic(); det.detect_batch([frame]); print(time.monotonic() - t0, flush=True)
"""


def _serve(asys: ActorSystem, path: str | None = None, options: dict[str, Any] | None = None) -> None:
    asys.spawn(ModelActor, MODEL, "detector", path or mtcnn_dir(), options or OPTIONS, True, wait=120, heartbeat=None)


@case("vision_pipeline", transport="embagents", kind="vision", needs="onnxruntime")
def vision_pipeline(opts: BenchOptions) -> dict[str, Any]:
    frames = 2 if opts.quick else 20
    frame = _frame(1920, 1080)
    runtime: list[float] = []
    inproc: list[float] = []
    with Baseline(_BASELINE, what="in-process detector") as baseline, ActorSystem() as asys:
        _serve(asys)
        asys.spawn(DetectionSink, "bench_vision_sink")
        asys.spawn(SteppingVision, "bench_vision", "bench_frames")
        got: queue.Queue[float] = queue.Queue()
        asys.rt.on_client(lambda: Subscription(asys.rt, asys.loop, "bench_latency", got.put, queue_size=100, keep="all"))
        pub = asys.rt.on_client(lambda: Publisher(asys.rt, "bench_frames"))
        time.sleep(0.5)  # subscriptions connected
        for _ in range(frames + 1):  # the first of each is a warm-up; interleaved, so drifts hit both
            asys.rt.on_client(lambda: pub.publish(Image(data=frame, stamp=time.monotonic(), frame_id="cam")))
            runtime.append(got.get(timeout=60))  # waited for, not polled: no CPU taken from the detector
            inproc.append(float(baseline.ask()))
        runtime, inproc = runtime[1:], inproc[1:]
    ours, base = statistics.median(runtime), statistics.median(inproc)
    return {
        "p50_us": ours * 1e6,
        "p99_us": max(runtime) * 1e6,
        "msgs_per_s": 1.0 / ours,
        "fps": 1.0 / ours,
        "ratio": ours / base,
        "inprocess_p50_us": base * 1e6,
        "note": f"1080p RGB, MTCNN, {len(runtime)} frames; bar: ratio <= 1.10",
    }


@case("model_actor_batching", transport="embagents", kind="vision", needs="onnx")
def model_actor_batching(opts: BenchOptions) -> dict[str, Any]:
    seconds, rounds = (0.5, 1) if opts.quick else (2.0, 5)
    ones: list[float] = []
    fours: list[float] = []
    with tempfile.TemporaryDirectory() as tmp, ActorSystem() as asys:
        _serve(asys, write_yolo_like(os.path.join(tmp, "yolo_like.onnx")), {"family": "yolo", "threshold": 0.9})
        comps = [asys.spawn(SteppingVision, f"bench_batch_{i}", None) for i in range(4)]
        comps[0].ask(["run", 0.2], timeout=60).get()  # warm the path
        for _ in range(rounds):  # interleaved, so drifts of the machine hit both alike
            ones.append(comps[0].ask(["run", seconds], timeout=seconds + 60).get() / seconds)
            futures = [c.ask(["run", seconds], timeout=seconds + 60) for c in comps]
            fours.append(sum(f.get() for f in futures) / seconds)
        stats = asys.ref(MODEL).ask("stats", timeout=10).get()
    one, four = statistics.median(ones), statistics.median(fours)
    return {
        "p50_us": 1e6 / four,
        "p99_us": max(1e6 / four, 1e6 / min(fours)),
        "msgs_per_s": four,
        "fps_one": one,
        "fps_four": four,
        "ratio": four / one,
        "max_batch_seen": stats["max_batch_seen"],
        "note": f"640x480 RGB, a YOLOv8-layout conv net (bench/yolo_like.py), median of {rounds} x {seconds:.1f} s; bar: ratio >= 1.5",
    }
