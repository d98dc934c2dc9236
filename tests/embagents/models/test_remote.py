"""Model actors reached over TCP with CURVE: a real model actor process, real sockets, real keys."""

from __future__ import annotations

import random
import re
import signal
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zmq

import embagents.msgs  # noqa: F401 - registers the message types
from actors import ActorSystem
from actors.curve import curve_client, load_secret_key, write_keypair
from embagents.models import (
    LocalModelClient,
    ModelCrashed,
    RemoteModelClient,
    RemoteRefused,
    collect_stream,
)
from embagents.models.protocol import InferError, InferRequest
from embagents.models.remote import RemoteModelActor
from tests.helpers import free_port, wait_until

HI = [{"role": "user", "content": "hello robot"}]


class Keys:
    """Key files of a server, an allowed client and a stranger in a private folder."""

    def __init__(self, folder: str) -> None:
        self.folder = folder
        self.server_pub, self.server = write_keypair(folder, "server")
        self.client_pub, self.client = write_keypair(folder, "client")
        self.stranger_pub, self.stranger = write_keypair(folder, "stranger")


@pytest.fixture()
def keys(tmp_path: Any) -> Keys:
    tmp_path.chmod(0o700)
    return Keys(str(tmp_path))


def spawn(asys: ActorSystem, name: str, kind: str, path: str, options: dict[str, Any], endpoint: str,
          keys: Keys) -> None:
    asys.spawn(RemoteModelActor, name, kind, path, options, True, None, [endpoint], keys.server,
               [keys.client_pub.decode()], wait=60)


@pytest.fixture()
def llm(tiny_gguf: str, keys: Keys) -> Iterator[tuple[ActorSystem, str, Keys]]:
    endpoint = f"tcp://127.0.0.1:{free_port()}"
    with ActorSystem() as asys:
        spawn(asys, "llm", "llama", tiny_gguf, {"n_ctx": 512, "seed": 0}, endpoint, keys)
        yield asys, endpoint, keys


def server_unread(port: int) -> int:
    """Bytes waiting unread in the established TCP connections whose local port is ``port`` (/proc/net/tcp)."""
    total = 0
    with open("/proc/net/tcp") as f:
        for line in f.readlines()[1:]:
            local, _remote, state, queues = line.split()[1:5]
            if int(local.split(":")[1], 16) == port and state == "01":
                total += int(queues.split(":")[1], 16)
    return total


def client_of(endpoint: str, keys: Keys, key: str | None = None, **kw: Any) -> RemoteModelClient:
    return RemoteModelClient(endpoint, server_key=keys.server_pub.decode(), key=key or keys.client, timeout=30, **kw)


def test_a_chat_stream_through_curve_tcp_comes_back_chunk_by_chunk(llm: Any) -> None:
    asys, endpoint, keys = llm
    chunks = list(client_of(endpoint, keys).chat_stream(HI, max_tokens=8))
    assert chunks[-1]["done"] and len(chunks) >= 2
    reply = collect_stream(chunks)
    assert reply["usage"]["completion_tokens"] >= 1
    # The same actor still serves its host's components over ipc, with the same answer (seed 0).
    assert LocalModelClient("llm", timeout=30).chat(HI, max_tokens=8)["content"] == reply["content"]


def test_a_client_whose_key_is_not_allowed_is_refused_at_once_and_counted(llm: Any) -> None:
    asys, endpoint, keys = llm
    t0 = time.monotonic()
    stranger = re.escape(keys.stranger_pub.decode())
    with pytest.raises(RemoteRefused, match=rf"refused this client's key {stranger} .*--allow {stranger}"):
        client_of(endpoint, keys, key=keys.stranger).chat(HI, max_tokens=4)
    assert time.monotonic() - t0 < 25  # well within its 30 s timeout: the refusal was seen, not waited out
    assert asys.ref("llm").ask("stats", timeout=5).get()["refused_keys"] >= 1
    assert client_of(endpoint, keys).chat(HI, max_tokens=4)["usage"]["completion_tokens"] >= 1


def test_a_client_pinning_another_server_key_fails_the_handshake(llm: Any) -> None:
    _, endpoint, keys = llm
    wrong = RemoteModelClient(endpoint, server_key=keys.stranger_pub.decode(), key=keys.client, timeout=30)
    with pytest.raises(RemoteRefused, match="handshake with .* failed 3 times: its key is not server_key"):
        wrong.chat(HI, max_tokens=4)


def test_a_server_killed_mid_request_fails_it_at_once_and_the_client_reconnects_to_its_restart(
        llm: Any, tiny_gguf: str) -> None:
    asys, endpoint, keys = llm
    client = client_of(endpoint, keys)
    box: list[BaseException] = []
    connected, asking = threading.Event(), threading.Event()

    long = [{"role": "user", "content": "hello robot " * 100}]  # a request frame no heartbeat is mistaken for

    def ask() -> None:
        client.chat(HI, max_tokens=2)  # this thread's connection is up
        connected.set()
        asking.wait(10)
        try:
            client.chat(long, max_tokens=4)
        except BaseException as exc:
            box.append(exc)

    t = threading.Thread(target=ask)
    t.start()
    assert connected.wait(30)
    asys.signal("llm", signal.SIGSTOP)  # it cannot answer now (sent through the fork server: wait for it)
    pid = asys.procs["llm"].pid
    wait_until(lambda: Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "T", 10, "stopped")
    asking.set()
    port = int(endpoint.rsplit(":", 1)[1])
    wait_until(lambda: server_unread(port) >= 1000, 10, "the request in the stopped server's socket buffer")
    asys.signal("llm", signal.SIGKILL)
    t.join(timeout=25)  # the client's own timeout is 30 s: failing before it means the death was seen
    assert not t.is_alive() and len(box) == 1 and isinstance(box[0], ModelCrashed), box
    asys.stop("llm")
    spawn(asys, "llm", "llama", tiny_gguf, {"n_ctx": 512, "seed": 0}, endpoint, keys)
    assert client.chat(HI, max_tokens=4)["usage"]["completion_tokens"] >= 1  # same client, same socket address


def test_garbage_on_the_tcp_port_is_dropped_and_authenticated_garbage_answered_while_it_serves_on(
        llm: Any) -> None:
    asys, endpoint, keys = llm
    pid = asys.procs["llm"].pid
    host, port = endpoint[len("tcp://"):].rsplit(":", 1)
    rng = random.Random(20)
    # Unauthenticated bytes: libzmq's CURVE handshake drops the peer before anything reaches the actor.
    for blob in (rng.randbytes(rng.randint(1, 4096)) for _ in range(20)):
        with socket.create_connection((host, int(port)), timeout=5) as s:
            s.sendall(b"\xff\x00\x00\x00\x00\x00\x00\x00\x01\x7f\x03\x00NULL" + blob)
    # Authenticated garbage: every frame gets an error answer, none stops the actor.
    pub, sec = load_secret_key(keys.client)
    ctx = zmq.Context.instance()
    raw = ctx.socket(zmq.DEALER)
    raw.linger = 0
    curve_client(raw, keys.server_pub, pub, sec)
    raw.connect(endpoint)
    try:
        sent = 0
        for _ in range(150):
            raw.send_multipart([rng.randbytes(rng.randint(0, 300)) for _ in range(rng.choice((1, 1, 1, 2, 3)))])
            sent += 1
        # A frame holding a shared-memory handle is refused over TCP (it would name a segment of the server's host).
        big, segments = asys.rt.codec.encode(InferRequest(id=7, task="chat", inputs={"a": np.zeros(1 << 20, np.uint8)}))
        assert segments  # the run's codec did put the array in shared memory
        raw.send(big)
        asys.rt.pool.acked(segments)
        sent += 1
        answers = []
        for _ in range(sent):
            assert raw.poll(20000), f"{len(answers)} answers of {sent}"
            answers.append(asys.rt.codec.decode(raw.recv()))
    finally:
        raw.close(0)
    assert all(isinstance(a, InferError) and a.kind == "bad_request" for a in answers), answers[:3]
    assert "shared-memory handle on a channel that does not accept them" in answers[-1].error
    assert client_of(endpoint, keys).chat(HI, max_tokens=4)["usage"]["completion_tokens"] >= 1
    assert asys.procs["llm"].pid == pid  # the same process served all along


def test_a_remote_detection_copies_the_frame_over_tcp(tiny_yolo: str, keys: Keys) -> None:
    endpoint = f"tcp://127.0.0.1:{free_port()}"
    with ActorSystem() as asys:
        spawn(asys, "det", "detector", tiny_yolo, {"family": "yolo", "threshold": 0.25}, endpoint, keys)
        out = client_of(endpoint, keys).detect(np.zeros((1080, 1920, 3), np.uint8))
        assert out["labels"] == ["robot"]
        assert out["boxes"].tolist() == [[660.0, 240.0, 1260.0, 840.0]]  # the same answer as through shared memory
        assert asys.ref("det").ask("stats", timeout=5).get()["served"] == 1


def test_a_system_using_a_remote_model_declares_no_local_model_actor_for_it(keys: Keys) -> None:
    from embagents import LLM, String, System, Topic
    from embagents.models import models_of
    from embagents.msgs import StreamingString

    llm = LLM(name="llm", inputs=[Topic("text_in", String)], outputs=[Topic("text_out", StreamingString)],
              model_client=client_of("tcp://gpu-box:5555", keys))
    assert models_of(System([llm], name="remote_llm")) == []  # the model actor runs elsewhere


def test_a_remote_client_refuses_a_plain_endpoint_and_an_unusable_key(keys: Keys) -> None:
    with pytest.raises(ValueError, match="not a TCP endpoint; pass tcp://HOST:PORT"):
        RemoteModelClient("ipc:///tmp/x", server_key=keys.server_pub.decode(), key=keys.client)
    with pytest.raises(ValueError, match="neither a public key"):
        RemoteModelClient("tcp://h:1", server_key="nope", key=keys.client)
    with pytest.raises(ValueError, match="no secret key file .*`embagents keys`"):
        RemoteModelClient("tcp://h:1", server_key=keys.server_pub.decode(), key=keys.folder + "/missing")
