"""A detector model actor in its own process, reached through the inference protocol."""

from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import zmq

pytest.importorskip("onnxruntime")

import embagents.models.client as client_module  # noqa: E402
import embagents.msgs  # noqa: E402,F401 - registers the message types
from actors import Actor, ActorSystem  # noqa: E402
from actors.runtime import current  # noqa: E402
from embagents.models import (  # noqa: E402
    BadRequest,
    LocalModelClient,
    ModelCrashed,
    ModelUnavailable,
    StaleInput,
)
from embagents.models.actor import ModelActor  # noqa: E402
from embagents.models.protocol import InferError, inference_endpoint  # noqa: E402
from tests.helpers import wait_until  # noqa: E402

OPTIONS = {"family": "yolo", "threshold": 0.25}


@pytest.fixture()
def served(tiny_yolo: str) -> Iterator[tuple[ActorSystem, LocalModelClient]]:
    with ActorSystem() as asys:
        asys.spawn(ModelActor, "det", "detector", tiny_yolo, OPTIONS, True, wait=60)
        yield asys, LocalModelClient("det", timeout=30)


def test_a_1080p_frame_goes_through_shared_memory_and_detections_come_back(served: Any) -> None:
    _, client = served
    out = client.detect(np.zeros((1080, 1920, 3), np.uint8))
    assert out["labels"] == ["robot"]
    assert out["boxes"].tolist() == [[660.0, 240.0, 1260.0, 840.0]]  # x 30 (1920 / 64), 14 px of padding off


def test_a_bad_request_is_answered_at_once_and_the_actor_keeps_serving(served: Any) -> None:
    _, client = served
    with pytest.raises(BadRequest, match=r"\(H, W, 3\) uint8 RGB array, got shape \(10, 10\) dtype float32"):
        client.detect(np.zeros((10, 10), np.float32))
    with pytest.raises(BadRequest, match="serves task 'detect', not 'chat'"):
        client.chat([{"role": "user", "content": "hi"}])
    with pytest.raises(BadRequest, match="unknown option"):
        client.detect(np.zeros((8, 8, 3), np.uint8), colour="red")
    assert client.detect(np.zeros((64, 64, 3), np.uint8))["labels"] == ["robot"]


def test_garbage_on_the_socket_gets_an_error_answer_and_the_actor_keeps_serving(served: Any) -> None:
    asys, client = served
    raw = asys.rt.ctx.socket(zmq.DEALER)
    raw.setsockopt(zmq.LINGER, 0)
    raw.connect(inference_endpoint(asys.rt.run_dir, "det"))
    try:
        raw.send(b"\xc1 not msgpack")
        assert raw.poll(10000)
        answer = asys.rt.codec.decode(raw.recv())
    finally:
        raw.close(0)
    assert isinstance(answer, InferError) and answer.kind == "bad_request" and "undecodable frame" in answer.error
    assert client.detect(np.zeros((64, 64, 3), np.uint8))["labels"] == ["robot"]


def _next_request_id() -> int:
    """The id the next request of this process will get (itertools.count shows it in its repr)."""
    return int(repr(client_module._req_ids)[len("count("):-1])


def test_a_request_to_a_model_actor_that_dies_fails_at_once(served: Any) -> None:
    asys, client = served
    client.detect(np.zeros((64, 64, 3), np.uint8))  # connected
    asys.signal("det", signal.SIGSTOP)  # it cannot answer now
    box: list[BaseException] = []

    def ask() -> None:
        try:
            client.detect(np.zeros((64, 64, 3), np.uint8))
        except BaseException as exc:
            box.append(exc)

    first = _next_request_id()
    t = threading.Thread(target=ask)
    t.start()
    # Kill only once the request is on its way (its id is taken after the client has read the
    # connection's older events): killed earlier, the request would wait for a restart of the
    # actor (as it should), not fail.
    wait_until(lambda: _next_request_id() > first, 10, "the request sent")
    asys.signal("det", signal.SIGKILL)
    t.join(timeout=25)  # the client's own timeout is 30 s: failing before it means the death was seen
    assert not t.is_alive() and len(box) == 1 and isinstance(box[0], ModelCrashed), box
    assert "went away" in str(box[0])


def test_four_clients_are_served_in_batches(served: Any) -> None:
    asys, _ = served
    results: list[int] = []

    def worker() -> None:
        c = LocalModelClient("det", timeout=30)
        for _ in range(20):
            results.append(len(c.detect(np.zeros((64, 64, 3), np.uint8))["labels"]))

    threads = [threading.Thread(target=worker) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    stats = asys.ref("det").ask("stats", timeout=5).get()
    assert results == [1] * 80 and stats["served"] >= 80
    assert stats["max_batch_seen"] > 1  # concurrent requests of several clients ran as one batch


def test_a_client_that_gives_up_cancels_its_request_in_the_model_actor(served: Any) -> None:
    asys, _ = served
    impatient = LocalModelClient("det", timeout=1)
    impatient.detect(np.zeros((64, 64, 3), np.uint8))  # connected
    before = asys.ref("det").ask("stats", timeout=5).get()
    asys.signal("det", signal.SIGSTOP)
    try:
        with pytest.raises(ModelUnavailable, match="sent nothing for 1 s"):
            impatient.detect(np.zeros((64, 64, 3), np.uint8))
    finally:
        asys.signal("det", signal.SIGCONT)
    # After SIGCONT the actor's ZeroMQ thread hands it the request and the cancel, usually together (the
    # request is dropped unserved) but now and then the request alone first (it is served, and the cancel
    # then finds nothing to stop): which one is not the test's to choose. Exactly one of the two, and the
    # answer that was asked for after it is the one the client takes.
    def outcome() -> tuple[int, int] | None:
        now = asys.ref("det").ask("stats", timeout=5).get()
        dropped, late = now["cancelled"] - before["cancelled"], now["cancels_late"] - before["cancels_late"]
        return (dropped, late) if dropped + late else None

    dropped, late = wait_until(outcome, what="the model actor to read the cancel")
    after = asys.ref("det").ask("stats", timeout=5).get()
    assert (dropped, late) in ((1, 0), (0, 1))
    assert after["served"] == before["served"] + late, "a cancelled request is never served"
    assert impatient.detect(np.zeros((64, 64, 3), np.uint8))["labels"] == ["robot"]  # the late answer is not taken


class FramePublisher(Actor):
    """A camera stand-in: publishes 1080p frames of one value on ``frames`` (its ring: 8 frames, 0.5 s)."""

    def on_receive(self, value: int) -> None:
        self.context.publish("frames", np.full((1080, 1920, 3), value, np.uint8))


class Detecting(Actor):
    """A Vision stand-in: detects in each frame it receives; says what came of each."""

    def on_start(self) -> None:
        self.results: list[str] = []
        self.client = LocalModelClient("det", timeout=30)
        self.context.subscribe("frames", self._on_frame, queue_size=1, keep="latest")

    def _on_frame(self, frame: np.ndarray) -> None:
        try:
            self.results.append(",".join(self.client.detect(frame)["labels"]))
        except StaleInput:
            self.results.append("stale")

    def on_receive(self, message: str) -> Any:
        if message == "segments":
            return current().pool.segment_count  # the frames this process wrote to shared memory
        return list(self.results)


class GatedModelActor(ModelActor):
    """A detector actor that, with its batch's frames read, writes ``<gate>.held`` and holds the batch
    until the file ``gate`` exists."""

    def __init__(self, gate: str, *args: Any) -> None:
        super().__init__(*args)
        self.gate = gate

    def _serve_batch(self, batch: list[Any]) -> None:
        if not os.path.exists(self.gate):
            open(self.gate + ".held", "w").close()
            wait_until(lambda: os.path.exists(self.gate), timeout=30, what="the test to open the gate")
        super()._serve_batch(batch)


def _camera_vision_detector(asys: ActorSystem, *detector: Any, actor: type = ModelActor) -> None:
    """Start the detector (``actor`` with ``detector`` args), the camera and Vision; return once a frame is through.

    Vision's subscription connects in its own time: the camera publishes until Vision has a result.
    """
    asys.spawn(actor, "det", *detector, wait=60)
    asys.spawn(FramePublisher, "cam", wait=30)
    asys.spawn(Detecting, "vision", wait=30)

    def seen() -> bool:
        asys.ref("cam").tell(0)
        return bool(asys.ref("vision").ask("results", timeout=30).get())

    wait_until(seen, timeout=30, interval=0.2, what="the first frame to be detected")


def test_a_camera_frame_reaches_the_detector_written_once(tiny_yolo: str) -> None:
    with ActorSystem() as asys:
        _camera_vision_detector(asys, "detector", tiny_yolo, OPTIONS, True)
        for value in range(1, 6):
            asys.ref("cam").ask(value, timeout=10).get()
        wait_until(lambda: len(asys.ref("vision").ask("results", timeout=30).get()) >= 3, what="more detections")
        assert set(asys.ref("vision").ask("results", timeout=30).get()) == {"robot"}
        # The frames went from the camera's ring to the detector: Vision's process wrote none of them.
        assert asys.ref("vision").ask("segments", timeout=30).get() == 0
        assert asys.ref("det").ask("stats", timeout=5).get()["stale"] == 0


def _come_round(asys: ActorSystem) -> None:
    """Publish until the camera's ring has reused every segment older than 0.5 s (the ring's rule)."""
    time.sleep(0.6)
    for value in range(2, 18):  # at most 8 kept; a segment of 0.5 s or older goes to the next frame
        asys.ref("cam").ask(value, timeout=10).get()


def test_a_frame_the_camera_overwrites_before_the_detector_reads_it_is_dropped(tiny_yolo: str) -> None:
    with ActorSystem() as asys:
        _camera_vision_detector(asys, "detector", tiny_yolo, OPTIONS, True)
        asys.signal("det", signal.SIGSTOP)
        try:
            asys.ref("cam").ask(1, timeout=10).get()  # Vision asks the stopped detector about this frame...
            _come_round(asys)  # ...and the camera reuses the frame's memory before the detector reads it
        finally:
            asys.signal("det", signal.SIGCONT)
        wait_until(lambda: "stale" in asys.ref("vision").ask("results", timeout=30).get(), what="a stale answer")
        assert asys.ref("det").ask("stats", timeout=5).get()["stale"] >= 1
        # The next frame is detected as ever: nothing is stuck.
        n = len(asys.ref("vision").ask("results", timeout=30).get())
        asys.ref("cam").ask(0, timeout=10).get()
        wait_until(lambda: len(asys.ref("vision").ask("results", timeout=30).get()) > n, what="the next frame")
        assert asys.ref("vision").ask("results", timeout=30).get()[-1] == "robot"


def test_a_frame_the_camera_overwrites_while_the_detector_runs_gives_no_answer(tiny_yolo: str,
                                                                                 tmp_path: Any) -> None:
    gate = str(tmp_path / "gate")
    open(gate, "w").close()
    with ActorSystem() as asys:
        _camera_vision_detector(asys, gate, "detector", tiny_yolo, OPTIONS, True, actor=GatedModelActor)
        os.unlink(gate)
        asys.ref("cam").ask(1, timeout=10).get()
        wait_until(lambda: os.path.exists(gate + ".held"), what="the detector to hold a frame it has read")
        _come_round(asys)  # the camera reuses it while the detector has it
        open(gate, "w").close()
        wait_until(lambda: "stale" in asys.ref("vision").ask("results", timeout=30).get(), what="a stale answer")
        assert asys.ref("det").ask("stats", timeout=5).get()["stale"] == 1
