"""LeRobotPolicyClient against a real gRPC policy server in another process, serving a tiny ONNX policy."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("grpc")
pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

from embagents.models import BadRequest  # noqa: E402
from embagents.models.lerobot import (  # noqa: E402
    LeRobotPolicyClient,
    PolicyError,
    PolicyUnavailable,
    decode_payload,
    encode_payload,
)
from embagents.models.policy import PolicyClient, PolicyLate  # noqa: E402
from tests.helpers import wait_until  # noqa: E402

TARGET = np.array([0.5, -0.3, 0.2, -1.5, 0.1, 1.2, 0.7], np.float32)
CHUNK = 8
STATE = np.zeros(7, np.float32)


GAIN = 0.2


@pytest.fixture(scope="module")
def policy(tmp_path_factory: pytest.TempPathFactory) -> str:
    """The model layer's reach policy (a P controller as an ONNX graph) that also takes a 480x640 camera image."""
    from embagents.models.backends.reach_policy import write_reach_policy

    return write_reach_policy(str(tmp_path_factory.mktemp("policy") / "reach.onnx"), TARGET, gain=GAIN, chunk=CHUNK,
                              camera="front", image_size=(480, 640))


def expected_chunk(state: np.ndarray) -> np.ndarray:
    steps = (1.0 - (1.0 - GAIN) ** np.arange(1, CHUNK + 1))[:, None]
    return (state[None, :] + steps * (TARGET - state)[None, :]).astype(np.float32)


CAMERA = np.zeros((480, 640, 3), np.uint8)  # 900 KB: travels to onnxruntime in the policy server


def obs(state: np.ndarray = STATE) -> dict[str, np.ndarray]:
    return {"observation.state": state, "observation.images.front": CAMERA}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextmanager
def serving(policy: str, port: int, *extra: str) -> Iterator[subprocess.Popen]:
    log = Path(policy).parent / f"server-{port}-{os.getpid()}.log"
    with open(log, "w") as out:
        proc = subprocess.Popen([sys.executable, "-m", "embagents.models.lerobot_server", "--onnx", policy,
                                 "--port", str(port), *extra], stdout=out, stderr=subprocess.STDOUT,
                                env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        def listening() -> bool:
            assert proc.poll() is None, f"the policy server exited: {log.read_text()}"
            return "serving " in log.read_text()

        wait_until(listening, 30.0, "the policy server listening", interval=0.05)
        yield proc
    finally:
        proc.terminate()
        proc.wait(timeout=10)


@pytest.fixture(scope="module")
def server(policy: str) -> Iterator[str]:
    port = _free_port()
    with serving(policy, port):
        yield f"127.0.0.1:{port}"


def test_a_chunk_comes_back_from_the_onnx_policy_behind_the_grpc_protocol(server: str) -> None:
    client = LeRobotPolicyClient(server, actions_per_chunk=CHUNK)
    assert isinstance(client, PolicyClient)
    try:
        state = np.linspace(-1, 1, 7).astype(np.float32)
        chunk = client.infer(obs(state), "reach", 5.0)  # the 900 KB frame: one chunk of the stream
        assert chunk.dtype == np.float32 and chunk.shape == (CHUNK, 7)
        assert np.allclose(chunk, expected_chunk(state), atol=1e-6)
        extra = np.zeros((1080, 1920, 3), np.uint8)  # 6 MB more: streamed in 2 MB chunks as LeRobot does
        assert client.infer({**obs(state), "observation.images.top": extra}, "reach", 5.0).shape == (CHUNK, 7)
    finally:
        client.close()


def test_an_observation_the_policy_cannot_take_is_refused_naming_the_keys(server: str) -> None:
    client = LeRobotPolicyClient(server, actions_per_chunk=CHUNK)
    try:
        with pytest.raises(BadRequest, match=r"observation lacks 'observation.state' .* keys sent: joints"):
            client.infer({"joints": STATE, "observation.images.front": CAMERA}, "reach", 5.0)
        assert client.infer(obs(), "reach", 5.0).shape == (CHUNK, 7)  # still serving
    finally:
        client.close()


def test_a_chunk_of_the_wrong_shape_names_expected_and_actual(server: str) -> None:
    client = LeRobotPolicyClient(server, actions_per_chunk=CHUNK + 2)  # the policy makes chunks of 8
    try:
        with pytest.raises(PolicyError, match=r"chunk of shape \(8, 7\); expected \(10, 7\) \(actions_per_chunk, n_joints\)"):
            client.infer(obs(), "reach", 5.0)
    finally:
        client.close()


def test_a_state_of_the_wrong_size_is_refused_naming_expected_and_actual(server: str) -> None:
    client = LeRobotPolicyClient(server, actions_per_chunk=CHUNK)
    try:
        with pytest.raises(BadRequest, match=r"observation 'observation.state' has shape \(6,\); the policy expects \(7,\)"):
            client.infer(obs(np.zeros(6, np.float32)), "reach", 5.0)
    finally:
        client.close()


def test_a_server_that_is_down_is_a_clear_error_and_the_client_reconnects_when_it_is_back(policy: str) -> None:
    port = _free_port()
    client = LeRobotPolicyClient(f"127.0.0.1:{port}", actions_per_chunk=CHUNK)
    try:
        with pytest.raises(PolicyUnavailable, match=rf"policy server 127.0.0.1:{port} is not reachable .*is it running"):
            client.infer(obs(), "reach", 2.0)
        with serving(policy, port):
            assert client.infer(obs(), "reach", 5.0).shape == (CHUNK, 7)
        with pytest.raises(PolicyUnavailable):  # gone again
            client.infer(obs(), "reach", 2.0)
        with serving(policy, port):  # a new server: a new hello and setup, then chunks again
            assert np.allclose(client.infer(obs(), "reach", 5.0),
                               expected_chunk(STATE))
    finally:
        client.close()


def test_a_server_that_forgot_the_setup_is_told_again_within_the_same_call(server: str) -> None:
    import grpc

    from embagents.models.lerobot import messages, method

    client = LeRobotPolicyClient(server, actions_per_chunk=CHUNK)
    try:
        assert client.infer(obs(), "reach", 5.0).shape == (CHUNK, 7)
        m = messages()
        with grpc.insecure_channel(server) as other:  # another client's Ready: the server forgets our setup
            other.unary_unary(method("Ready"), request_serializer=lambda x: x.SerializeToString(),
                              response_deserializer=m["Empty"].FromString)(m["Empty"](), timeout=5)
        assert np.allclose(client.infer(obs(), "reach", 5.0), expected_chunk(STATE))
    finally:
        client.close()


def test_a_late_answer_is_a_timeout_error(policy: str) -> None:
    port = _free_port()
    with serving(policy, port, "--latency-s", "1.5"):
        client = LeRobotPolicyClient(f"127.0.0.1:{port}", actions_per_chunk=CHUNK)
        try:
            with pytest.raises(PolicyLate, match=r"gave no actions within 0.300 s; motion should stop"):
                client.infer(obs(), "reach", 0.3)
            assert client.infer(obs(), "reach", 5.0).shape == (CHUNK, 7)  # patient: served
        finally:
            client.close()


def test_pickles_are_never_loaded_and_there_is_no_switch_to_load_them() -> None:
    import pickle

    with pytest.raises(ValueError, match="a pickle: LeRobot's own encoding, which this side never loads"):
        decode_payload(pickle.dumps({"actions": [1.0]}))
    with pytest.raises(TypeError, match="allow_pickle"):
        LeRobotPolicyClient("127.0.0.1:1", actions_per_chunk=4, allow_pickle=True)  # type: ignore[call-arg]
    with pytest.raises(TypeError, match="only numeric arrays"):
        encode_payload({"x": np.array([object()])})
    assert decode_payload(encode_payload({"a": np.arange(3, dtype=np.int16)}))["a"].tolist() == [0, 1, 2]


def test_a_pickle_sent_to_our_server_is_refused_not_loaded(server: str, tmp_path: Path) -> None:
    import pickle

    import grpc

    from embagents.models.lerobot import messages, method

    marker = tmp_path / "ran"
    evil = pickle.dumps(_Evil(str(marker)))
    m = messages()
    with grpc.insecure_channel(server) as channel:
        send = channel.unary_unary(method("SendPolicyInstructions"), request_serializer=lambda x: x.SerializeToString(),
                                   response_deserializer=m["Empty"].FromString)
        with pytest.raises(grpc.RpcError) as err:
            send(m["PolicySetup"](data=evil), timeout=5)
    assert err.value.code() == grpc.StatusCode.INVALID_ARGUMENT and "never loads" in err.value.details()
    assert not marker.exists()


class _Evil:
    def __init__(self, path: str) -> None:
        self.path = path

    def __reduce__(self) -> tuple:
        return (open, (self.path, "w"))


def test_a_channel_that_leaves_the_machine_is_named_plaintext_in_a_warning(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level("WARNING", "embagents.models.lerobot")
    for address in ("127.0.0.1:8080", "localhost:8080", "[::1]:8080"):
        LeRobotPolicyClient(address, actions_per_chunk=CHUNK)
    assert not caplog.records  # loopback stays on the machine: nothing to warn of
    LeRobotPolicyClient("10.1.2.3:8080", actions_per_chunk=CHUNK, name="arm")
    [record] = caplog.records
    assert "arm: the LeRobot gRPC channel to 10.1.2.3:8080 is plaintext and unauthenticated" in record.getMessage()


@pytest.fixture(scope="module")
def tls_files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """A self-signed certificate for 127.0.0.1, its key, and a token file."""
    folder = tmp_path_factory.mktemp("tls")
    cert, key, token = folder / "cert.pem", folder / "key.pem", folder / "token"
    out = subprocess.run(["openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1",
                          "-nodes", "-keyout", str(key), "-out", str(cert), "-days", "1", "-subj", "/CN=127.0.0.1",
                          "-addext", "subjectAltName=IP:127.0.0.1"], capture_output=True, text=True, timeout=60)
    if out.returncode != 0:
        pytest.skip(f"openssl could not make a test certificate: {out.stderr.strip()[-200:]}")
    token.write_text("s3cret-token\n")
    return {"cert": str(cert), "key": str(key), "token": str(token)}


def test_over_tls_with_a_token_a_chunk_comes_back_and_a_wrong_token_or_plaintext_is_refused(
        policy: str, tls_files: dict[str, str], caplog: pytest.LogCaptureFixture) -> None:
    port = _free_port()
    with serving(policy, port, "--tls-cert", tls_files["cert"], "--tls-key", tls_files["key"],
                 "--token-file", tls_files["token"]):
        address = f"127.0.0.1:{port}"
        good = LeRobotPolicyClient(address, actions_per_chunk=CHUNK, tls_ca=tls_files["cert"], token="s3cret-token")
        wrong = LeRobotPolicyClient(address, actions_per_chunk=CHUNK, tls_ca=tls_files["cert"], token="guess")
        plain = LeRobotPolicyClient(address, actions_per_chunk=CHUNK)
        try:
            assert np.allclose(good.infer(obs(), "reach", 10.0), expected_chunk(STATE), atol=1e-6)
            with pytest.raises(PolicyError, match="refused this client: no valid token"):
                wrong.infer(obs(), "reach", 10.0)
            with pytest.raises((PolicyUnavailable, PolicyError)):  # a plaintext client gets no TLS handshake
                plain.infer(obs(), "reach", 5.0)
        finally:
            for c in (good, wrong, plain):
                c.close()
    with pytest.raises(ValueError, match="a token needs TLS"):
        LeRobotPolicyClient(address, actions_per_chunk=CHUNK, token="s3cret-token")
    caplog.set_level("WARNING", "embagents.models.lerobot")
    LeRobotPolicyClient("10.1.2.3:8080", actions_per_chunk=CHUNK, tls_ca=tls_files["cert"], token="t")
    assert not caplog.records  # TLS and a token: nothing to warn of
