"""Mutual TLS between bridges: certificates from `embagents keys --tls`; a peer of another CA is refused and logged."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from embagents.zenoh import TlsFiles, ZenohBridge
from tests.embagents.zenoh.runs import RECEIVER, SENDER, Run, free_port, wait_for, write

pytest.importorskip("zenoh")
pytest.importorskip("cryptography")


def _keys(folder: Path, host: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "embagents.cli", "keys", "--tls", "--host", host, "--dir", str(folder)],
                          capture_output=True, text=True, timeout=60)


def test_peers_of_one_ca_link_and_a_peer_of_another_ca_is_refused_and_logged(tmp_path: Path) -> None:
    fleet, other = tmp_path / "fleet", tmp_path / "other"
    fleet.mkdir(mode=0o700), other.mkdir(mode=0o700)
    for folder, host in ((fleet, "robot1"), (fleet, "gpu"), (other, "intruder")):
        out = _keys(folder, host)
        assert out.returncode == 0, out.stderr
        assert out.stdout.strip() == str(folder / f"{host}.pem")
    assert oct(os.stat(fleet / "gpu.key").st_mode & 0o777) == "0o600"
    assert oct(os.stat(fleet / "ca.key").st_mode & 0o777) == "0o600"
    again = _keys(fleet, "gpu")
    assert again.returncode == 1 and "already exists" in again.stderr  # a key is never overwritten

    port = free_port()
    runs = str(tmp_path / "runs")

    def tls(folder: Path, host: str) -> str:
        return f"tls=TlsFiles.of_host({str(folder)!r}, {host!r})"

    a = Run(write(tmp_path, "robot_a", SENDER, f"listen=['tls/127.0.0.1:{port}'], {tls(fleet, 'robot1')}"), runs)
    b = Run(write(tmp_path, "gpu_b", RECEIVER, f"connect=['tls/127.0.0.1:{port}'], {tls(fleet, 'gpu')}"), runs)
    c = Run(write(tmp_path, "intruder_c", RECEIVER, f"connect=['tls/127.0.0.1:{port}'], {tls(other, 'intruder')}",
                  link_down_s=1.0), runs)
    try:
        wait_for(lambda: len(b.got()) >= 10, 60, "messages over TLS on run B")
        detail = wait_for(lambda: (d := c.bridge()) and d["health"] == "SYSTEM_FAILURE" and d["links"][0]["last_error"]
                          and d, 60, "the intruder's link never up")
        assert detail["links"][0]["state"] == "never up"
        assert "wrong or missing certificate" in detail["links"][0]["last_error"]
        assert c.got() == []
        wait_for(lambda: any("zenoh_link_tls" in x and ("DecryptError" in x or "alert" in x) for x in a.all), 30,
                 "the refusal in run A's log")
    finally:
        for r in (c, b, a):
            r.stop()


def test_access_rules_let_a_named_peer_have_its_keys_and_nothing_else(tmp_path: Path) -> None:
    fleet = tmp_path / "fleet"
    fleet.mkdir(mode=0o700)
    for host in ("robot1", "gpu", "laptop"):
        assert _keys(fleet, host).returncode == 0
    port = free_port()
    runs = str(tmp_path / "runs")

    def tls(host: str) -> str:
        return f"tls=TlsFiles.of_host({str(fleet)!r}, {host!r})"

    # robot1 lets gpu have robot*/chatter (the key gpu subscribes to); laptop (a certificate of the same CA) is named nowhere.
    a = Run(write(tmp_path, "acl_robot", SENDER, f"listen=['tls/127.0.0.1:{port}'], {tls('robot1')}, "
                  "peers={'gpu': ['robot*/chatter']}"), runs)
    b = Run(write(tmp_path, "acl_gpu", RECEIVER, f"connect=['tls/127.0.0.1:{port}'], {tls('gpu')}"), runs)
    c = Run(write(tmp_path, "acl_laptop", RECEIVER, f"connect=['tls/127.0.0.1:{port}'], {tls('laptop')}"), runs)
    try:
        wait_for(lambda: len(b.got()) >= 20, 60, "messages for the named peer")
        n = len(c.got())
        assert n == 0, "".join(c.all[-20:])
    finally:
        for r in (c, b, a):
            r.stop()


def test_plain_tcp_beyond_loopback_and_tls_without_certificates_are_refused_naming_the_fix(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"plain TCP beyond loopback is not allowed; use 'tls/192.168.1.20:7447' "
                                         r"with tls=TlsFiles"):
        ZenohBridge("robot1", connect=["tcp/192.168.1.20:7447"])
    with pytest.raises(ValueError, match=r"needs certificates: give the bridge tls=TlsFiles"):
        ZenohBridge("robot1", listen=["tls/0.0.0.0:7447"])
    with pytest.raises(ValueError, match=r"malformed endpoint 'tcp:127.0.0.1:7447': write PROTOCOL/HOST:PORT"):
        ZenohBridge("robot1", listen=["tcp:127.0.0.1:7447"])
    with pytest.raises(ValueError, match=r"does not exist; make it with `embagents keys --tls --host NAME`"):
        TlsFiles.of_host(str(tmp_path), "robot1")
    with pytest.raises(ValueError, match=r"peers= \(access rules by certificate name\) needs tls="):
        ZenohBridge("robot1", listen=["tcp/127.0.0.1:7447"], peers={"gpu": ["robot1/**"]})
    with pytest.raises(TypeError, match=r"write \['tcp/127.0.0.1:7447'\]"):
        ZenohBridge("robot1", listen="tcp/127.0.0.1:7447")  # type: ignore[arg-type]


def test_a_malformed_endpoint_in_system_py_stops_supervise_with_the_fix(tmp_path: Path) -> None:
    path = write(tmp_path, "bad_ep", SENDER, "listen=['tcp/127.0.0.1']")
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "supervise", path], capture_output=True, text=True,
                         timeout=60, env={**os.environ, "EMBAGENTS_RUNS_DIR": str(tmp_path / "runs")})
    assert out.returncode == 1
    assert "malformed endpoint 'tcp/127.0.0.1': write PROTOCOL/HOST:PORT" in out.stdout + out.stderr
