"""`embagents serve-model`: a supervised model actor reached over CURVE, on loopback and from another netns."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

import embagents.msgs  # noqa: F401 - registers the message types
from actors import ActorSystem
from actors.curve import write_keypair
from embagents.models import RemoteModelClient, RemoteRefused
from tests.helpers import free_port, wait_until

HI = [{"role": "user", "content": "hello robot"}]


class Served:
    """An `embagents serve-model` process (optionally inside a network namespace) and its stderr."""

    def __init__(self, argv: list[str], prefix: list[str]) -> None:
        self.proc = subprocess.Popen([*prefix, sys.executable, "-m", "embagents.cli", "serve-model", *argv],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        self.lines: list[str] = []
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.lines.append(line)

    def log(self) -> str:
        return "".join(self.lines)

    def status(self) -> dict[str, Any] | None:
        out = subprocess.run([sys.executable, "-m", "embagents.cli", "status", "--json", "--run", str(self.proc.pid)],
                             capture_output=True, text=True, timeout=60)
        return json.loads(out.stdout) if out.returncode == 0 else None

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)  # a clean stop: the tree stops, the run's files go
        try:
            return self.proc.wait(timeout=60)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
                self.proc.wait()
            self.reader.join(10)


def keys_in(folder: Path) -> dict[str, Any]:
    folder.chmod(0o700)
    return {who: write_keypair(str(folder), who) for who in ("server", "client", "stranger")}


def serve(tiny_gguf: str, keys: dict[str, Any], host: str, port: int, prefix: list[str]) -> Served:
    served = Served([tiny_gguf, "--bind", f"tcp://{host}:{port}", "--allow", keys["client"][0].decode(),
                     "--key", keys["server"][1]], prefix)
    wait_until(lambda: "embagents: serving model" in served.log() or served.proc.poll() is not None, 120,
               "serve-model ready")
    assert served.proc.poll() is None, served.log()
    return served


def client(keys: dict[str, Any], host: str, port: int, who: str = "client") -> RemoteModelClient:
    return RemoteModelClient(f"tcp://{host}:{port}", server_key=keys["server"][0].decode(), key=keys[who][1],
                             timeout=30)


def check_serving(served: Served, keys: dict[str, Any], host: str, port: int, peer: str) -> None:
    """A chat works, a stranger is refused and logged with its address and key."""
    with ActorSystem():
        assert client(keys, host, port).chat(HI, max_tokens=4)["usage"]["completion_tokens"] >= 1
        with pytest.raises(RemoteRefused, match="not on the server's allow list"):
            client(keys, host, port, "stranger").chat(HI, max_tokens=4)
    stranger = keys["stranger"][0].decode()
    wait_until(lambda: f"refused a client from {peer}: public key {stranger} is not on the allow list" in served.log(),
               10, "the refusal in the server's log")


def test_serve_model_is_supervised_and_serves_allowed_keys_on_loopback(tmp_path: Path, tiny_gguf: str) -> None:
    keys = keys_in(tmp_path)
    port = free_port()
    served = serve(tiny_gguf, keys, "127.0.0.1", port, [])
    try:
        check_serving(served, keys, "127.0.0.1", port, "127.0.0.1")
        st = served.status()
        assert st is not None
        (row,) = st["rows"]
        assert row["name"] == "tiny_llama" and row["status"] == "running"
        os.kill(row["pid"], signal.SIGKILL)  # the supervisor restarts the model actor on the same port

        def restarted() -> Any:
            rows = (served.status() or {}).get("rows", [])
            return rows and rows[0]["restarts"] == 1 and rows[0]["status"] == "running"

        wait_until(restarted, 60, "the model actor restarted", interval=0.2)
        with ActorSystem():
            assert client(keys, "127.0.0.1", port).chat(HI, max_tokens=4)["usage"]["completion_tokens"] >= 1
    finally:
        code = served.stop()
    assert code == 0, served.log()


def test_serve_model_survives_deep_frames_silent_and_null_peers_and_logs_each_refusal(tmp_path: Path, tiny_gguf: str) -> None:
    import resource
    import socket
    import time

    import zmq

    from actors import Codec
    from actors.curve import curve_client, load_secret_key
    from embagents.models.protocol import InferError
    from tests.actors.test_codec import nested_frame

    keys = keys_in(tmp_path)
    port = free_port()
    served = serve(tiny_gguf, keys, "127.0.0.1", port, [])
    try:
        st = served.status()
        assert st is not None
        pid = st["rows"][0]["pid"]
        # A silent peer holds a file descriptor only for the 5 s handshake limit (libzmq's default: 30 s).
        idle = socket.create_connection(("127.0.0.1", port), timeout=20)
        t0 = time.monotonic()
        assert idle.recv(4096)[:1] == b"\xff" and idle.recv(4096) == b""  # the server's greeting, then the close
        assert 3 < time.monotonic() - t0 < 15
        idle.close()
        # An allowed client's frame of 10,000 nested messages (200 used to kill the model actor) is answered.
        ctx = zmq.Context.instance()
        raw = ctx.socket(zmq.DEALER)
        raw.linger = 0
        curve_client(raw, keys["server"][0], *load_secret_key(keys["client"][1]))
        raw.connect(f"tcp://127.0.0.1:{port}")
        try:
            for levels in (200, 10_000):
                raw.send(nested_frame(levels))
                assert raw.poll(20000)
                answer = Codec().decode(raw.recv())
                assert isinstance(answer, InferError) and "nested more than 32 deep" in answer.error
        finally:
            raw.close(0)
        null = ctx.socket(zmq.DEALER)  # no CURVE: refused before the allow list is asked, and logged
        null.linger = 0
        null.connect(f"tcp://127.0.0.1:{port}")
        null.send(b"hello")
        # Which side sees the mismatch first is a race: either way the refusal is logged.
        wait_until(lambda: re.search(r"refused a client from .*: (it does not speak CURVE|it hung up during the handshake) "
                                     r"\(a NULL or PLAIN client", served.log()), 10, "the refusal logged")
        assert re.search(r"refused a client from 127\.0\.0\.1:\d+: it did not finish its handshake within 5 s", served.log())
        null.close(0)
        with ActorSystem():
            assert client(keys, "127.0.0.1", port).chat(HI, max_tokens=4)["usage"]["completion_tokens"] >= 1
        st = served.status()
        assert st is not None and st["rows"][0]["pid"] == pid and st["rows"][0]["restarts"] == 0
        hard = resource.getrlimit(resource.RLIMIT_NOFILE)[1]  # the soft limit was raised to it
        assert f"up to {hard} open files" in served.log()
    finally:
        code = served.stop()
    assert code == 0, served.log()


@pytest.fixture()
def netns() -> Iterator[tuple[str, str, str]]:
    """A network namespace with a veth pair: (namespace, host address, namespace address); removed after."""
    tag = f"ea{os.getpid() % 100000}"
    ns, host_if, ns_if = f"{tag}-ns", f"{tag}h", f"{tag}n"
    setup = [
        ["ip", "netns", "add", ns],
        ["ip", "link", "add", host_if, "type", "veth", "peer", "name", ns_if],
        ["ip", "link", "set", ns_if, "netns", ns],
        ["ip", "addr", "add", "10.231.7.1/30", "dev", host_if],
        ["ip", "link", "set", host_if, "up"],
        ["ip", "netns", "exec", ns, "ip", "addr", "add", "10.231.7.2/30", "dev", ns_if],
        ["ip", "netns", "exec", ns, "ip", "link", "set", ns_if, "up"],
        ["ip", "netns", "exec", ns, "ip", "link", "set", "lo", "up"],
    ]
    try:
        for cmd in setup:
            out = subprocess.run(cmd, capture_output=True, text=True, timeout=30)
            if out.returncode != 0:
                pytest.skip(f"cannot make a network namespace here ({' '.join(cmd)}: {out.stderr.strip()}); "
                            "it needs root or CAP_NET_ADMIN and the `ip` tool")
        yield ns, "10.231.7.1", "10.231.7.2"
    except FileNotFoundError:
        pytest.skip("no `ip` tool (iproute2) to make a network namespace")
    finally:
        subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=30)
        subprocess.run(["ip", "link", "del", host_if], capture_output=True, timeout=30)


def test_serve_model_in_another_network_namespace_is_reached_over_a_veth(
        tmp_path: Path, tiny_gguf: str, netns: tuple[str, str, str]) -> None:
    ns, host_addr, ns_addr = netns
    keys = keys_in(tmp_path)
    served = serve(tiny_gguf, keys, ns_addr, 5555, ["ip", "netns", "exec", ns])
    try:
        check_serving(served, keys, ns_addr, 5555, host_addr)
    finally:
        code = served.stop()
    assert code == 0, served.log()


def test_model_names_a_builtin_a_file_or_a_model_a_system_declares(tmp_path: Path) -> None:
    from embagents.cli.serve_model import model_of

    system = tmp_path / "system.py"
    system.write_text("from embagents import LlamaModel, System\n"
                      "system = System([], name='gpu', models=[LlamaModel(name='brain', n_ctx=1024)])\n")
    brain = model_of(f"{system}:brain")
    assert brain.name == "brain" and brain.options()["n_ctx"] == 1024
    with pytest.raises(ValueError, match="declares no model 'eyes'; it declares: brain"):
        model_of(f"{system}:eyes")
    with pytest.raises(ValueError, match="MODEL 'gpt-9' is not known: pass smollm2 or faces"):
        model_of("gpt-9")
    assert model_of("faces").options()["family"] == "mtcnn"


def test_a_tcp_bind_without_keys_is_refused_naming_the_fix(tmp_path: Path) -> None:
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "serve-model", "smollm2", "--bind", "tcp://127.0.0.1:5555"],
                         capture_output=True, text=True, timeout=60, env={**os.environ, "XDG_CONFIG_HOME": str(tmp_path)})
    assert out.returncode == 1
    assert "unauthenticated TCP is not offered; make keys with `embagents keys` and pass --key" in out.stderr


def test_a_public_key_file_given_as_key_names_the_secret_file_to_pass(tmp_path: Path) -> None:
    keys = keys_in(tmp_path)
    public_file = keys["server"][1][: -len("_secret")]
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "serve-model", "smollm2", "--bind", "tcp://127.0.0.1:5555",
                          "--allow", keys["client"][0].decode(), "--key", public_file],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 1
    assert f"{public_file} is a public key (it holds no secret key): pass {keys['server'][1]}" in out.stderr


def test_an_allowed_key_that_starts_with_a_dash_is_taken_as_the_key(tmp_path: Path) -> None:
    # Z85 has "-" in its alphabet: about one public key in 85 starts with it, and argparse took it for an option.
    from embagents.cli import _keys_attached, build_parser

    key = "-[UnAGwJQBF2O7&2zL+<@g[$NF)xF4q-6RKN)DTA"
    args = build_parser().parse_args(_keys_attached(["serve-model", "m.gguf", "--bind", "tcp://127.0.0.1:1",
                                                     "--allow", key]))
    assert args.allow == [key]
