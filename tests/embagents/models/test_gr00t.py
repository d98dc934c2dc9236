"""Gr00tPolicyClient against a small GR00T-protocol server in another process (ZeroMQ REP, msgpack, np.save).

The server below follows Isaac GR00T's ``gr00t/policy/server_client.py`` as
documented: requests ``{"endpoint", "data", "api_token"}``, arrays as
``{"__ndarray_class__": True, "as_npy": np.save bytes}``, errors as
``{"error": text}``. It is written against msgpack and numpy directly, not
with our codec, so the encoding is checked against the format, not against itself.
"""

from __future__ import annotations

import io
import os
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager

import msgpack
import numpy as np
import pytest

from embagents.models.gr00t import Gr00tPolicyClient, decode, encode
from embagents.models.lerobot import PolicyError
from embagents.models.policy import PolicyClient, PolicyLate
from embagents.models.protocol import BadRequest
from tests.helpers import free_port

SERVER = r'''
import io, sys, time
import msgpack, numpy as np, zmq

port, token, mode = int(sys.argv[1]), sys.argv[2] or None, sys.argv[3]

def enc(o):
    if isinstance(o, np.ndarray):
        b = io.BytesIO(); np.save(b, o, allow_pickle=False)
        return {"__ndarray_class__": True, "as_npy": b.getvalue()}
    return o

def dec(o):
    if "__ndarray_class__" in o:
        return np.load(io.BytesIO(o["as_npy"]), allow_pickle=False)
    return o

sock = zmq.Context().socket(zmq.REP)
sock.bind(f"tcp://127.0.0.1:{port}")
print("ready", flush=True)
n = 0
while True:
    req = msgpack.unpackb(sock.recv(), object_hook=dec)
    n += 1
    if mode == "silent":
        continue  # never answers (a REP socket that never sends takes nothing more either)
    if mode == "slow_first" and n == 1:
        time.sleep(1.0)  # answers too late: the client has given up and reset its socket
    if token is not None and req.get("api_token") != token:
        sock.send(msgpack.packb({"error": "Unauthorized: Invalid API token"})); continue
    ep = req.get("endpoint", "get_action")
    if ep == "ping":
        sock.send(msgpack.packb({"status": "ok"})); continue
    if ep == "get_modality_config":
        sock.send(msgpack.packb({"state": {"modality_keys": ["state.single_arm", "state.gripper"]}})); continue
    data = req["data"]
    try:
        arm, grip = data["state.single_arm"], data["state.gripper"]
        assert arm.shape == (1, 5) and grip.shape == (1, 1), (arm.shape, grip.shape)
        assert data["video.front"].shape == (1, 24, 32, 3) and data["video.front"].dtype == np.uint8
        assert data["annotation.human.task_description"] == ["pick the cup"]
        steps = np.arange(1, 17, dtype=np.float32)[:, None]
        out = {"action.single_arm": arm[0] + 0.01 * steps, "action.gripper": grip[0] + 0.0 * steps}
        if mode == "short":
            out = {k: v[:4] for k, v in out.items()}
        sock.send(msgpack.packb(out, default=enc))
    except Exception as e:
        sock.send(msgpack.packb({"error": f"{type(e).__name__}: {e}"}))
'''

STATE = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 1.0], np.float32)
OBS = {"observation.state": STATE, "observation.images.front": np.zeros((24, 32, 3), np.uint8)}
PARTS = {"state.single_arm": 5, "state.gripper": 1}
ACTIONS = ["action.single_arm", "action.gripper"]


@contextmanager
def gr00t_server(mode: str = "ok", token: str = "") -> Iterator[str]:
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-c", SERVER, str(port), token, mode], stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "ready"
        yield f"tcp://127.0.0.1:{port}"
    finally:
        proc.kill()
        proc.wait(timeout=10)


def client(endpoint: str, **kw: object) -> Gr00tPolicyClient:
    return Gr00tPolicyClient(endpoint, state_keys=PARTS, action_keys=ACTIONS, **kw)  # type: ignore[arg-type]


def test_a_chunk_comes_back_from_a_gr00t_protocol_server_with_the_state_split_into_parts() -> None:
    with gr00t_server() as url:
        c = client(url)
        assert isinstance(c, PolicyClient)
        try:
            chunk = c.infer(OBS, "pick the cup", 5.0)
            assert chunk.shape == (16, 6) and chunk.dtype == np.float32
            np.testing.assert_allclose(chunk[0], STATE + np.r_[[0.01] * 5, 0.0], rtol=1e-6)
            assert c.ping() and c.modality_config()["state"]["modality_keys"] == list(PARTS)
        finally:
            c.close()


def test_the_array_encoding_is_gr00ts_documented_one() -> None:
    wire = msgpack.unpackb(encode({"x": np.arange(6, dtype=np.int16).reshape(2, 3)}))
    assert wire["x"]["__ndarray_class__"] is True
    np.testing.assert_array_equal(np.load(io.BytesIO(wire["x"]["as_npy"]), allow_pickle=False),
                                  np.arange(6, dtype=np.int16).reshape(2, 3))
    buf = io.BytesIO()
    np.save(buf, np.array([1.5, 2.5], np.float32), allow_pickle=False)
    assert decode(msgpack.packb({"y": {"__ndarray_class__": True, "as_npy": buf.getvalue()}}))["y"].tolist() == [1.5, 2.5]


def test_a_pickled_object_array_is_refused_never_loaded() -> None:
    buf = io.BytesIO()
    np.save(buf, np.array([{"a": 1}], dtype=object), allow_pickle=True)  # what a hostile server could send
    with pytest.raises(ValueError, match="not a GR00T message.*(pickle|allow_pickle)"):
        decode(msgpack.packb({"action.arm": {"__ndarray_class__": True, "as_npy": buf.getvalue()}}))
    with pytest.raises(ValueError, match="dtype complex64 are refused"):
        encode({"x": np.zeros(2, np.complex64)})


def test_a_server_that_never_answers_is_late_and_the_req_socket_is_reset_each_time() -> None:
    with gr00t_server("silent") as url:
        c = client(url)
        try:
            for _ in range(3):  # a stuck REQ socket would raise "Operation cannot be accomplished" on the 2nd send
                with pytest.raises(PolicyLate, match="no answer to 'get_action' within 0.2 s.*socket was reset"):
                    c.infer(OBS, "pick the cup", 0.2)
            assert c.resets == 3
        finally:
            c.close()


def test_after_a_lost_answer_the_next_call_gets_its_own_answer() -> None:
    with gr00t_server("slow_first") as url:
        c = client(url)
        try:
            with pytest.raises(PolicyLate):
                c.infer(OBS, "pick the cup", 0.2)
            chunk = c.infer(OBS, "pick the cup", 5.0)  # the late answer went to the closed socket, not here
            assert chunk.shape == (16, 6)
        finally:
            c.close()


def test_a_token_is_sent_and_a_wrong_one_is_named() -> None:
    with gr00t_server(token="s3cret") as url:
        c = client(url, api_token="s3cret")
        try:
            assert c.infer(OBS, "pick the cup", 5.0).shape == (16, 6)
        finally:
            c.close()
        c = client(url, api_token="wrong")
        try:
            with pytest.raises(PolicyError, match="Unauthorized.*pass the server's token"):
                c.infer(OBS, "pick the cup", 5.0)
        finally:
            c.close()


def test_the_servers_error_and_a_chunk_of_the_wrong_shape_are_named() -> None:
    with gr00t_server() as url:
        c = client(url)
        try:
            with pytest.raises(PolicyError, match="failed: AssertionError"):
                c.infer({**OBS, "observation.images.front": np.zeros((8, 8, 3), np.uint8)}, "pick the cup", 5.0)
            with pytest.raises(BadRequest, match="add up to 6 joints, the state has 7"):
                c.infer({**OBS, "observation.state": np.zeros(7, np.float32)}, "pick the cup", 5.0)
        finally:
            c.close()
    with gr00t_server("short") as url:
        c = client(url, actions_per_chunk=16)
        try:
            with pytest.raises(PolicyError, match=r"shape \(4, 6\).*expected \(16, 6\)"):
                c.infer(OBS, "pick the cup", 5.0)
        finally:
            c.close()
