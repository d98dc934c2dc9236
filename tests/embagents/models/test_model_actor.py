"""A detector model actor in its own process, reached through the inference protocol."""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import zmq

pytest.importorskip("onnxruntime")

import embagents.models.client as client_module  # noqa: E402
import embagents.msgs  # noqa: E402,F401 - registers the message types
from actors import ActorSystem  # noqa: E402
from embagents.models import BadRequest, LocalModelClient, ModelCrashed, ModelUnavailable  # noqa: E402
from embagents.models.protocol import InferError, inference_endpoint  # noqa: E402
from embagents.runtime.model_actor import ModelActor  # noqa: E402
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
