"""Two runs in two network namespaces joined by a veth pair (made here, removed in a finally):
mutual TLS beyond loopback, and a link cut by taking the veth down."""

from __future__ import annotations

import os
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from embagents.cli.keys import make_ca, make_host
from tests.embagents.zenoh.runs import RECEIVER, SENDER, Run, wait_for, write

pytest.importorskip("zenoh")
pytest.importorskip("cryptography")

TAG = f"ez{os.getpid() % 100000}"
NS_A, NS_B, VETH_A, VETH_B = f"{TAG}a", f"{TAG}b", f"{TAG}va", f"{TAG}vb"
ADDR_A, ADDR_B = "10.231.7.1", "10.231.7.2"


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True, timeout=30)


@pytest.fixture()
def namespaces() -> Iterator[None]:
    try:
        _ip("netns", "add", NS_A)
    except (OSError, subprocess.CalledProcessError) as exc:
        pytest.skip(f"cannot make network namespaces here ({getattr(exc, 'stderr', exc)!s}); needs root and iproute2")
    try:
        _ip("netns", "add", NS_B)
        _ip("link", "add", VETH_A, "type", "veth", "peer", "name", VETH_B)
        for ns, dev, addr in ((NS_A, VETH_A, ADDR_A), (NS_B, VETH_B, ADDR_B)):
            _ip("link", "set", dev, "netns", ns)
            _ip("-n", ns, "addr", "add", f"{addr}/24", "dev", dev)
            _ip("-n", ns, "link", "set", dev, "up")
            _ip("-n", ns, "link", "set", "lo", "up")
        yield
    finally:
        for ns in (NS_A, NS_B):  # deleting a namespace deletes its end of the veth, and so the pair
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=30)


def test_two_namespaces_link_over_tls_and_a_veth_cut_loses_nothing(namespaces: None, tmp_path: Path) -> None:
    certs = tmp_path / "certs"
    certs.mkdir(mode=0o700)
    make_ca(str(certs))
    make_host(str(certs), "robot1", [ADDR_A])
    make_host(str(certs), "gpu", [ADDR_B])

    def tls(host: str) -> str:
        return f"tls=TlsFiles.of_host({str(certs)!r}, {host!r})"

    runs = str(tmp_path / "runs")
    a = Run(write(tmp_path, "ns_robot", SENDER, f"listen=['tls/{ADDR_A}:7447'], {tls('robot1')}", rate=50.0), runs,
            prefix=["ip", "netns", "exec", NS_A])
    b = Run(write(tmp_path, "ns_gpu", RECEIVER, f"connect=['tls/{ADDR_A}:7447'], {tls('gpu')}", link_down_s=1.0), runs,
            prefix=["ip", "netns", "exec", NS_B])
    try:
        wait_for(lambda: len(b.got()) >= 20, 60, "messages across the namespaces")
        detail = b.bridge()
        assert detail is not None and detail["links"][0]["state"] == "up", detail
        _ip("-n", NS_A, "link", "set", VETH_A, "down")
        # A silent peer: down once the 3 s lease runs out, SYSTEM_FAILURE 1 s later (link_down_s).
        down = wait_for(lambda: (d := b.bridge()) and d["health"] == "SYSTEM_FAILURE" and d, 30,
                        "SYSTEM_FAILURE while the veth is down")
        assert down["links"][0]["state"] == "down"
        before = len(b.got())
        _ip("-n", NS_A, "link", "set", VETH_A, "up")
        wait_for(lambda: len(b.got()) >= before + 200, 60, "the messages of the cut")
        wait_for(lambda: (d := b.bridge()) and d["health"] == "HEALTHY", 30, "HEALTHY after the veth is up")
        got = b.got()
        assert got == list(range(got[0], got[0] + len(got)))  # every message once, in order
        assert b.bridge()["counts"]["lost"] == 0  # type: ignore[index]
    finally:
        b.stop(), a.stop()
