"""openpi's WebSocket policy protocol: `embagents serve-policy` against openpi's own client code, and ours.

openpi's client (``openpi-client`` 0.1.2 on PyPI) pins numpy<2 and needs
dm-tree; its protocol modules need only msgpack, numpy and websockets, so they
are loaded from the wheel's files (fetched and cached by the project's own
:mod:`embagents.models.files.wheels`) instead of installing the package: a real peer.
"""

from __future__ import annotations

import importlib.util
import logging
import os
import re
import subprocess
import sys
import time
import types
import urllib.error
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest

# openpi's client holds its connection outside a with block, which websockets >= 17.1 warns about
pytestmark = pytest.mark.filterwarnings(r"ignore:connect\(\) must be used as a context manager:DeprecationWarning")

pytest.importorskip("websockets")
pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

from embagents.models.lerobot import PolicyError, PolicyUnavailable  # noqa: E402
from embagents.models.openpi import OpenPIPolicyClient, packb, unpackb  # noqa: E402
from embagents.models.policy import PolicyClient, PolicyLate  # noqa: E402
from embagents.models.protocol import BadRequest  # noqa: E402
from tests.helpers import free_port, wait_until  # noqa: E402

TARGET = np.array([0.5, -0.3, 0.2, -1.5, 0.1, 1.2, 0.7], np.float32)
CHUNK, GAIN = 8, 0.2
STATE = np.zeros(7, np.float32)
CAMERA = np.zeros((48, 64, 3), np.uint8)
KEY_MAP = {"observation.state": "observation/state", "observation.images.front": "observation/image", "task": "prompt"}


def expected_chunk(state: np.ndarray) -> np.ndarray:
    steps = (1.0 - (1.0 - GAIN) ** np.arange(1, CHUNK + 1))[:, None]
    return (state[None, :] + steps * (TARGET - state)[None, :]).astype(np.float32)


@pytest.fixture(scope="module")
def openpi_client() -> types.ModuleType:
    """openpi_client's modules, loaded from the files of its PyPI wheel (not installed: its pins clash)."""
    from embagents.models.files.wheels import WheelFileError, wheel_file

    pkg = types.ModuleType("openpi_client")
    pkg.__path__ = []
    saved = {k: sys.modules.get(k) for k in ("openpi_client", "openpi_client.base_policy",
                                             "openpi_client.msgpack_numpy", "openpi_client.websocket_client_policy")}
    sys.modules["openpi_client"] = pkg
    try:
        for name in ("base_policy", "msgpack_numpy", "websocket_client_policy"):
            try:
                path = wheel_file("openpi-client", f"openpi_client/{name}.py", version="0.1.2", progress=False)
            except WheelFileError as exc:
                pytest.skip(f"openpi-client's wheel is not at hand: {exc}")
            spec = importlib.util.spec_from_file_location(f"openpi_client.{name}", path)
            assert spec is not None and spec.loader is not None
            module = importlib.util.module_from_spec(spec)
            sys.modules[spec.name] = module
            spec.loader.exec_module(module)
            setattr(pkg, name, module)
    finally:
        for k, v in saved.items():  # nothing of it stays importable for other tests
            if v is None:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = v
    return pkg


@pytest.fixture(scope="module")
def policy(tmp_path_factory: pytest.TempPathFactory) -> str:
    from embagents.models.backends.reach_policy import write_reach_policy

    return write_reach_policy(str(tmp_path_factory.mktemp("policy") / "reach.onnx"), TARGET, gain=GAIN, chunk=CHUNK,
                              camera="front", image_size=(48, 64))


def healthy(url: str) -> bool:
    try:
        with urllib.request.urlopen(url.replace("ws://", "http://", 1) + "/healthz", timeout=1) as r:
            return r.status == 200 and r.read() == b"OK\n"
    except (OSError, urllib.error.URLError):
        return False


@contextmanager
def serve_policy(policy: str, port: int, *extra: str) -> Iterator[str]:
    """``embagents serve-policy POLICY --bind ws://127.0.0.1:PORT`` in its own process, until /healthz answers."""
    url = f"ws://127.0.0.1:{port}"
    log = Path(policy).parent / f"serve-policy-{port}-{os.getpid()}-{time.monotonic_ns()}.log"
    with open(log, "w") as out:
        proc = subprocess.Popen([sys.executable, "-m", "embagents.cli", "serve-policy", policy, "--bind", url, *extra],
                                stdout=out, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        def up() -> bool:
            assert proc.poll() is None, f"serve-policy exited: {log.read_text()}"
            return healthy(url)

        wait_until(up, 60.0, "serve-policy answering /healthz", interval=0.1)
        yield url
    finally:
        proc.terminate()
        proc.wait(timeout=20)
        assert proc.returncode == 0, log.read_text()


@pytest.fixture(scope="module")
def server(policy: str) -> Iterator[str]:
    with serve_policy(policy, free_port()) as url:
        yield url


def test_openpis_own_client_drives_our_onnx_policy_through_serve_policy(server: str,
                                                                        openpi_client: types.ModuleType) -> None:
    client = openpi_client.websocket_client_policy.WebsocketClientPolicy(server)
    meta = client.get_server_metadata()
    assert meta["observation_keys"] == ["observation.state", "observation.images.front"]
    assert meta["actions_per_chunk"] == CHUNK and meta["action_dim"] == 7
    state = np.linspace(-0.5, 0.5, 7).astype(np.float32)
    first = client.infer({"observation/state": state, "observation/images/front": CAMERA, "prompt": "reach"})
    np.testing.assert_allclose(first["actions"], expected_chunk(state), rtol=1e-5, atol=1e-6)
    # openpi's nested style reaches the same inputs; the second answer times the first one too
    second = client.infer({"observation": {"state": state, "images": {"front": CAMERA}}, "prompt": "reach"})
    np.testing.assert_allclose(second["actions"], first["actions"])
    assert first["server_timing"]["infer_ms"] > 0 and "prev_total_ms" not in first["server_timing"]
    assert second["server_timing"]["prev_total_ms"] >= second["server_timing"]["infer_ms"] > 0


def test_our_client_reads_the_metadata_and_returns_the_chunk_with_server_timing(server: str) -> None:
    client = OpenPIPolicyClient(server, key_map={"observation.state": "observation/state",
                                                 "observation.images.front": "observation/images/front"})
    assert isinstance(client, PolicyClient)
    try:
        state = np.full(7, 0.1, np.float32)
        chunk = client.infer({"observation.state": state, "observation.images.front": CAMERA}, "reach", 5.0)
        assert chunk.dtype == np.float32 and chunk.shape == (CHUNK, 7)
        np.testing.assert_allclose(chunk, expected_chunk(state), rtol=1e-5, atol=1e-6)
        assert client.metadata is not None and client.metadata["action_key"] == "actions"
        client.infer({"observation.state": state, "observation.images.front": CAMERA}, "reach", 5.0)
        assert set(client.server_timing) == {"infer_ms", "prev_total_ms"}
        assert client.timing["roundtrip_ms"] > 0 and client.connects == 1  # one connection for both
    finally:
        client.close()


def test_the_wire_format_is_openpis_both_ways(openpi_client: types.ModuleType) -> None:
    theirs = openpi_client.msgpack_numpy
    value = {"state": np.arange(7, dtype=np.float32), "image": np.arange(24, dtype=np.uint8).reshape(2, 4, 3),
             "mask": np.array([True, False]), "step": np.int64(3), "gain": np.float32(0.5), "prompt": "pick",
             "nested": {"ids": np.array([[1, 2]], np.int32)}}
    for decoded in (theirs.unpackb(packb(value)), unpackb(theirs.packb(value))):
        assert decoded["prompt"] == "pick" and decoded["step"] == 3 and decoded["step"].dtype == np.int64
        assert decoded["gain"].dtype == np.float32
        for key in ("state", "image", "mask"):
            assert decoded[key].dtype == value[key].dtype
            np.testing.assert_array_equal(decoded[key], value[key])
        np.testing.assert_array_equal(decoded["nested"]["ids"], value["nested"]["ids"])
    assert packb(value) == theirs.packb(value)  # byte for byte the same message


@pytest.mark.parametrize("bad", [np.zeros(2, complex), np.array([object()]), np.zeros(2, [("a", "<i4")])],
                         ids=["complex", "object", "void"])
def test_object_void_and_complex_arrays_are_refused_both_ways(bad: np.ndarray, openpi_client: types.ModuleType) -> None:
    with pytest.raises(ValueError, match=re.escape(f"dtype {bad.dtype}") + ".* are refused"):
        packb({"x": bad})
    forged = msgpack.packb({b"x": {b"__ndarray__": True, b"data": b"\0" * 16, b"dtype": bad.dtype.str,
                                   b"shape": [1]}}, use_bin_type=True)
    with pytest.raises(ValueError, match="refused|not an openpi"):
        unpackb(forged)  # never turned into an object array, whatever its bytes


def test_an_observation_the_server_cannot_take_is_a_traceback_then_close_1011_shown_once(
        server: str, openpi_client: types.ModuleType) -> None:
    from websockets.exceptions import ConnectionClosedError
    from websockets.sync.client import connect

    with connect(server, compression=None) as ws:  # openpi's error frames, as its client sees them
        unpackb(ws.recv(timeout=5))
        ws.send(packb({"observation/state": STATE}))  # no camera image: the policy needs one
        text = ws.recv(timeout=5)
        assert isinstance(text, str) and text.startswith("Traceback") and "observation.images.front" in text
        with pytest.raises(ConnectionClosedError) as closed:
            ws.recv(timeout=5)
        assert closed.value.rcvd is not None and closed.value.rcvd.code == 1011

    client = OpenPIPolicyClient(server, key_map={"observation.state": "observation/state"})
    with pytest.raises(BadRequest, match=r"needs observation keys \['observation.images.front'\]"):
        client.infer({"observation.state": STATE}, "reach", 5.0)  # named from the metadata, before anything is sent
    client.close()
    client = OpenPIPolicyClient(server, retry_after_error_s=30)
    bad = {"observation.state": np.zeros(6, np.float32), "observation.images.front": CAMERA}
    with pytest.raises(PolicyError, match=r"(?s)failed:\nTraceback.*'observation.state' has shape \(6,\)") as first:
        client.infer(bad, "reach", 5.0)
    with pytest.raises(PolicyError) as again:
        client.infer(bad, "reach", 5.0)
    assert str(again.value) == str(first.value) and client.connects == 1  # not asked again: no loop of tracebacks
    client.close()


def test_a_metadata_without_the_keys_the_client_needs_is_named(server: str) -> None:
    client = OpenPIPolicyClient(server, required_metadata=["action_horizon", "actions_per_chunk", "norm_stats"])
    with pytest.raises(PolicyError, match="metadata lacks 'action_horizon', 'norm_stats'"):
        client.connect()


def test_a_chunk_of_the_wrong_shape_names_both_shapes(server: str) -> None:
    client = OpenPIPolicyClient(server, actions_per_chunk=5)
    try:
        with pytest.raises(PolicyError, match=r"shape \(8, 7\); expected \(5, 7\) \(actions_per_chunk, n_joints\)"):
            client.infer({"observation.state": STATE, "observation.images.front": CAMERA}, "reach", 5.0)
    finally:
        client.close()


def test_a_refused_dtype_is_named_before_anything_is_sent(server: str) -> None:
    client = OpenPIPolicyClient(server)
    try:
        with pytest.raises(BadRequest, match="dtype complex128 are refused"):
            client.infer({"observation.state": STATE.astype(complex), "observation.images.front": CAMERA}, "x", 5.0)
    finally:
        client.close()


def test_the_client_reconnects_after_the_server_restarts(policy: str) -> None:
    port = free_port()
    client = OpenPIPolicyClient(f"ws://127.0.0.1:{port}")
    obs = {"observation.state": STATE, "observation.images.front": CAMERA}
    with pytest.raises(PolicyUnavailable, match="not reachable.*serve-policy"):
        client.infer(obs, "reach", 1.0)
    with serve_policy(policy, port):
        assert client.infer(obs, "reach", 5.0).shape == (CHUNK, 7)
    with pytest.raises(PolicyUnavailable):
        client.infer(obs, "reach", 1.0)  # it went away: said, and the next call reconnects
    with serve_policy(policy, port):
        assert client.infer(obs, "reach", 5.0).shape == (CHUNK, 7)
    assert client.connects == 2
    client.close()


def test_a_late_answer_is_policy_late_and_skipped_when_it_comes(policy: str) -> None:
    with serve_policy(policy, free_port(), "--delay-ms", "300") as url:
        client = OpenPIPolicyClient(url)
        try:
            with pytest.raises(PolicyLate, match="no actions within 0.05 s"):
                client.infer({"observation.state": STATE, "observation.images.front": CAMERA}, "reach", 0.05)
            state = np.full(7, 0.3, np.float32)
            chunk = client.infer({"observation.state": state, "observation.images.front": CAMERA}, "reach", 5.0)
            np.testing.assert_allclose(chunk, expected_chunk(state), rtol=1e-5, atol=1e-6)  # not the old answer
        finally:
            client.close()


def test_an_api_key_is_checked_and_a_browser_origin_refused(policy: str, tmp_path: Path,
                                                             openpi_client: types.ModuleType) -> None:
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    key = tmp_path / "api_key"
    key.write_text("k" * 32 + "\n")
    key.chmod(0o600)
    with serve_policy(policy, free_port(), "--api-key-file", str(key)) as url:
        theirs = openpi_client.websocket_client_policy.WebsocketClientPolicy(url, api_key="k" * 32)
        assert theirs.get_server_metadata()["actions_per_chunk"] == CHUNK
        with pytest.raises(InvalidStatus, match="401"):
            openpi_client.websocket_client_policy.WebsocketClientPolicy(url, api_key="k" * 31 + "x")
        with pytest.raises(PolicyError, match=r"refused this client \(401.*pass the API key"):
            OpenPIPolicyClient(url).connect()
        assert OpenPIPolicyClient(url, api_key="k" * 32).connect()["action_dim"] == 7
        with pytest.raises(InvalidStatus, match="403"):
            connect(url, origin="http://evil.example", additional_headers={"Authorization": "Api-Key " + "k" * 32})


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "embagents.cli", "serve-policy", *args], capture_output=True,
                          text=True, timeout=60)


def test_beyond_loopback_without_tls_or_a_key_is_refused_naming_the_fix(policy: str, tmp_path: Path) -> None:
    out = run_cli(policy, "--bind", "ws://0.0.0.0:8000")
    assert out.returncode == 1 and "--api-key-file FILE" in out.stderr and "wss://" in out.stderr
    key = tmp_path / "loose"
    key.write_text("k" * 32)
    key.chmod(0o644)
    out = run_cli(policy, "--bind", "ws://0.0.0.0:8000", "--api-key-file", str(key))
    assert out.returncode == 1 and "readable by others" in out.stderr and "chmod 600" in out.stderr
    out = run_cli(policy, "--bind", "wss://127.0.0.1:8000")
    assert out.returncode == 1 and "--tls-cert" in out.stderr
    out = run_cli(str(tmp_path / "nothing.onnx"), "--bind", "ws://127.0.0.1:8000")
    assert out.returncode == 1 and "not found" in out.stderr


@pytest.fixture(scope="module")
def six_joint_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A policy for a 6-joint arm: the 7-joint Panda's observations fail on the server's side."""
    from embagents.models.backends.reach_policy import write_reach_policy

    path = write_reach_policy(str(tmp_path_factory.mktemp("six") / "six.onnx"), TARGET[:6], gain=GAIN, chunk=CHUNK)
    with serve_policy(path, free_port()) as url:
        yield url


def test_a_vla_shows_the_servers_traceback_once_in_its_health_and_holds(six_joint_server: str, caplog: Any) -> None:
    pytest.importorskip("pybullet")
    from embagents.components import HealthStatus
    from tests.embagents.components.test_vla import Loop

    client = OpenPIPolicyClient(six_joint_server, retry_after_error_s=30.0)
    lp = Loop(policy=client)
    try:
        with caplog.at_level(logging.WARNING, "embagents.component.vla"):
            lp.vla.manipulate("reach", 100)
            lp.tick(20)
        assert lp.vla.health.status == HealthStatus.ALGORITHM_FAILURE
        assert "Traceback" in lp.vla.health.text and "has shape (7,)" in lp.vla.health.text
        assert sum("Traceback" in r.getMessage() for r in caplog.records) == 1  # once, not per tick
        assert lp.vla.step == 0 and client.connects == 1  # held, and asked the server once
    finally:
        lp.close()


def test_a_vla_surfaces_the_servers_timing_in_its_status_and_on_a_metrics_topic(server: str) -> None:
    import json

    from embagents.components import VLA, VLAConfig
    from embagents.msgs import Image, JointState, String
    from embagents.topic import Topic

    states, command, camera, metrics = (Topic("joints", JointState), Topic("command", JointState),
                                        Topic("camera", Image), Topic("vla/metrics", String))
    joints = [f"j{i}" for i in range(7)]
    vla = VLA(name="vla", inputs=[states, camera], outputs=[command, metrics],
              policy=OpenPIPolicyClient(server), trigger=50.0,
              config=VLAConfig(joint_names_map={j: j for j in joints}, camera_inputs_map={"front": camera.name},
                               joint_limits={j: {"lower": -3.0, "upper": 3.0, "velocity": 2.0} for j in joints},
                               actions_per_chunk=CHUNK))
    sent: list[tuple[str, object]] = []
    vla.attach(lambda topic, msg: sent.append((topic, msg)))
    try:
        vla.manipulate("reach", 100)
        for _ in range(6):
            vla.on_message(states.name, JointState(name=joints, position=np.zeros(7)))
            vla.on_message(camera.name, Image(data=CAMERA))
            vla.execute()
        status = vla.status()
        assert status["step"] == 6 and status["chunks"] >= 2 and status["policy_latency_ms"] > 0
        assert status["server_timing"]["infer_ms"] > 0 and "prev_total_ms" in status["server_timing"]
        said = [json.loads(m.data) for t, m in sent if t == metrics.name]  # type: ignore[attr-defined]
        assert len(said) == status["chunks"] and said[-1]["server_timing"] == status["server_timing"]
        assert said[-1]["policy"] == "openpi" and said[-1]["last_latency_ms"] > 0
    finally:
        vla.on_shutdown()


@pytest.fixture(scope="module")
def tls_files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """A self-signed certificate for 127.0.0.1 and its key."""
    folder = tmp_path_factory.mktemp("tls")
    cert, key = folder / "cert.pem", folder / "key.pem"
    out = subprocess.run(["openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1",
                          "-nodes", "-keyout", str(key), "-out", str(cert), "-days", "1", "-subj", "/CN=127.0.0.1",
                          "-addext", "subjectAltName=IP:127.0.0.1"], capture_output=True, text=True, timeout=60)
    if out.returncode != 0:
        pytest.skip(f"openssl could not make a test certificate: {out.stderr.strip()[-200:]}")
    return {"cert": str(cert), "key": str(key)}


def test_over_wss_the_client_checks_the_servers_certificate(policy: str, tls_files: dict[str, str]) -> None:
    port = free_port()
    log = Path(policy).parent / f"wss-{port}.log"
    with open(log, "w") as out:
        proc = subprocess.Popen([sys.executable, "-m", "embagents.cli", "serve-policy", policy, "--bind",
                                 f"wss://127.0.0.1:{port}", "--tls-cert", tls_files["cert"], "--tls-key",
                                 tls_files["key"]], stdout=out, stderr=subprocess.STDOUT)
    try:
        wait_until(lambda: "serving policy" in log.read_text() or proc.poll() is not None, 60.0, "serve-policy up")
        assert proc.poll() is None, log.read_text()
        obs = {"observation.state": STATE, "observation.images.front": CAMERA}
        client = OpenPIPolicyClient(f"wss://127.0.0.1:{port}", tls_ca=tls_files["cert"])
        assert client.infer(obs, "reach", 5.0).shape == (CHUNK, 7)
        client.close()
        with pytest.raises(PolicyUnavailable, match="CERTIFICATE_VERIFY_FAILED|certificate"):
            OpenPIPolicyClient(f"wss://127.0.0.1:{port}").infer(obs, "reach", 5.0)  # not trusted: refused
    finally:
        proc.terminate()
        proc.wait(timeout=20)


def test_serve_policy_serves_a_policy_model_that_a_system_declares(policy: str, tmp_path: Path) -> None:
    from embagents.cli.serve_policy import policy_of

    system = tmp_path / "robot.py"
    system.write_text("from embagents.models import LlamaModel, PolicyModel\nfrom embagents.system import System\n"
                      f"reach = PolicyModel(name='reach', local_model_path={policy!r})\n"
                      "chat = LlamaModel(name='chat', local_model_path='chat.gguf')\n"
                      "system = System([], models=[reach, chat])\n")
    with pytest.raises(ValueError, match="is a llama model, not a policy"):
        policy_of(f"{system}:chat")
    with serve_policy(f"{system}:reach", free_port()) as url:
        client = OpenPIPolicyClient(url)
        assert client.infer({"observation.state": STATE, "observation.images.front": CAMERA}, "x", 5.0).shape == (CHUNK, 7)
        client.close()
