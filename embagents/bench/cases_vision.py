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
  ``ratio`` = frames per second served, four / one.
"""

from __future__ import annotations

import statistics
import time
from typing import Any

import numpy as np

import embagents.msgs  # noqa: F401 - registers the message types this case decodes
from actors import Actor, ActorSystem
from actors.topics import Publisher
from embagents.bench.registry import BenchOptions, case

__all__ = ["DetectionSink", "SteppingVision"]

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
        from embagents.components import Vision
        from embagents.models import LocalModelClient
        from embagents.msgs import Detections, Image
        from embagents.topic import Topic

        inp = Topic(self.topic or "bench_unused", Image)
        self.vision = Vision(name=self.name, inputs=[inp], outputs=[Topic("bench_detections", Detections)],
                             model_client=LocalModelClient(MODEL))
        self.vision.attach(lambda topic, msg: self.context.publish(topic, msg))
        self.image = Image(data=_frame(*self.size), frame_id=self.name)
        if self.topic:
            self.context.subscribe(self.topic, self._on_frame, queue_size=2)

    def _on_frame(self, msg: Any) -> None:
        if self.vision.on_message(self.topic, msg):
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
    """Notes when each Detections arrives, against its frame's stamp."""

    def on_start(self) -> None:
        self.latencies: list[float] = []
        self.context.subscribe("bench_detections", self._on_det, queue_size=100, keep="all")

    def _on_det(self, det: Any) -> None:
        self.latencies.append(time.monotonic() - det.stamp)

    def on_receive(self, message: Any) -> Any:
        return list(self.latencies)


def _serve(asys: ActorSystem) -> None:
    from embagents.modelfiles import mtcnn_dir
    from embagents.runtime.model_actor import ModelActor

    asys.spawn(ModelActor, MODEL, "detector", mtcnn_dir(), OPTIONS, True, wait=120, heartbeat=None)


@case("vision_pipeline", transport="embagents", kind="vision", needs="onnxruntime")
def vision_pipeline(opts: BenchOptions) -> dict[str, Any]:
    from embagents.backends.detectors import make_detector
    from embagents.modelfiles import mtcnn_dir
    from embagents.msgs import Image

    frames = 2 if opts.quick else 20
    frame = _frame(1920, 1080)
    detector = make_detector(mtcnn_dir(), **OPTIONS)  # after the fork server started: no threads forked
    runtime: list[float] = []
    inproc: list[float] = []
    with ActorSystem() as asys:
        _serve(asys)
        sink = asys.spawn(DetectionSink, "bench_vision_sink")
        asys.spawn(SteppingVision, "bench_vision", "bench_frames")
        pub = asys.rt.on_client(lambda: Publisher(asys.rt, "bench_frames"))
        time.sleep(0.5)  # subscriptions connected
        for i in range(frames + 1):  # the first of each is a warm-up; interleaved, so drifts hit both
            asys.rt.on_client(lambda: pub.publish(Image(data=frame, stamp=time.monotonic(), frame_id="cam")))
            deadline = time.monotonic() + 60
            while len(got := sink.ask("latencies", timeout=10).get()) <= i and time.monotonic() < deadline:
                time.sleep(0.002)
            t0 = time.monotonic()
            detector.detect_batch([frame])
            inproc.append(time.monotonic() - t0)
        runtime, inproc = got[1:], inproc[1:]
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


@case("model_actor_batching", transport="embagents", kind="vision", needs="onnxruntime")
def model_actor_batching(opts: BenchOptions) -> dict[str, Any]:
    seconds = 1.0 if opts.quick else 6.0
    with ActorSystem() as asys:
        _serve(asys)
        comps = [asys.spawn(SteppingVision, f"bench_batch_{i}", None) for i in range(4)]
        comps[0].ask(["run", 0.2], timeout=60).get()  # warm the path
        one = comps[0].ask(["run", seconds], timeout=seconds + 60).get() / seconds
        futures = [c.ask(["run", seconds], timeout=seconds + 60) for c in comps]
        four = sum(f.get() for f in futures) / seconds
        stats = asys.ref(MODEL).ask("stats", timeout=10).get()
    return {
        "p50_us": 1e6 / four,
        "p99_us": 1e6 / one,
        "msgs_per_s": four,
        "fps_one": one,
        "fps_four": four,
        "ratio": four / one,
        "max_batch_seen": stats["max_batch_seen"],
        "note": f"640x480 RGB, MTCNN, {seconds:.0f} s each; bar: ratio >= 1.5",
    }
