"""CURVE key files and the ZAP allow list, with real key pairs and real ZeroMQ handshakes."""

from __future__ import annotations

import logging
import os
import re
import socket
import time
from pathlib import Path

import pytest
import zmq
from zmq.utils import z85

from actors.curve import (
    CurveAllowList,
    KeyFileError,
    curve_client,
    curve_server,
    load_public_key,
    load_secret_key,
    write_keypair,
)
from tests.helpers import wait_until


@pytest.fixture()
def folder(tmp_path: Path) -> str:
    tmp_path.chmod(0o700)
    return str(tmp_path)


def test_a_secret_key_file_others_can_read_is_refused_with_the_fix(folder: str) -> None:
    _, secret = write_keypair(folder, "robot")
    assert os.stat(secret).st_mode & 0o777 == 0o600
    os.chmod(secret, 0o644)
    with pytest.raises(KeyFileError, match=rf"mode 644.*Fix: `chmod 600 {secret}`"):
        load_secret_key(secret)


def test_a_key_pair_is_never_overwritten_and_names_are_file_names(folder: str) -> None:
    public, secret = write_keypair(folder, "robot")
    with pytest.raises(KeyFileError, match="never overwritten"):
        write_keypair(folder, "robot")
    with pytest.raises(KeyFileError, match="a file name, not a path"):
        write_keypair(folder, "../robot")
    assert load_secret_key(secret)[0] == public == load_public_key(secret[: -len("_secret")])


def test_a_public_key_file_is_not_a_secret_key_and_nonsense_is_neither(folder: str) -> None:
    _, secret = write_keypair(folder, "robot")
    public_file = secret[: -len("_secret")]
    # As written (readable by all, as a public key may be) it used to be refused with `chmod 600`.
    for mode in (0o644, 0o600):
        os.chmod(public_file, mode)
        with pytest.raises(KeyFileError, match=f"robot.key is a public key \\(it holds no secret key\\): pass {re.escape(secret)}$"):
            load_secret_key(public_file)
    with pytest.raises(KeyFileError, match="neither a public key"):
        load_public_key("not-a-key")


def test_the_allow_list_lets_in_only_its_keys_and_counts_and_logs_the_others(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, "actors.curve")
    ctx = zmq.Context()
    server_pub, server_sec = zmq.curve_keypair()
    good_pub, good_sec = zmq.curve_keypair()
    bad_pub, bad_sec = zmq.curve_keypair()
    router = ctx.socket(zmq.ROUTER)
    auth = CurveAllowList(ctx, [good_pub], watch=router)
    curve_server(router, server_sec)
    port = router.bind_to_random_port("tcp://127.0.0.1")
    socks = []
    try:
        for pub, sec in ((bad_pub, bad_sec), (None, None), (good_pub, good_sec)):
            d = ctx.socket(zmq.DEALER)
            socks.append(d)
            if pub is not None:
                curve_client(d, server_pub, pub, sec)
            d.connect(f"tcp://127.0.0.1:{port}")
            d.send(b"hello")
        assert router.poll(10000)
        frames = router.recv_multipart(copy=False)
        assert frames[1].bytes == b"hello" and frames[1].get("User-Id") == good_pub.decode()
        assert not router.poll(500)  # neither the stranger nor the NULL client got a frame in
        # The stranger, refused by ZAP, and the NULL client, which fails before ZAP is asked: both logged.
        wait_until(lambda: auth.refused == 2, 5, "both refusals")  # the NULL one: a mismatch, or a hang-up (a race)
        assert f"public key {bad_pub.decode()} is not on the allow list" in caplog.text
        # A NULL client over a real network: its greeting comes a round trip after the connection, so
        # its address is still there to be logged (on loopback libzmq may close it before it is looked up).
        with socket.create_connection(("127.0.0.1", port)) as raw:
            raw.sendall(b"\xff" + bytes(8) + b"\x7f")
            time.sleep(0.3)
            raw.sendall(bytes([3, 0]) + b"NULL".ljust(20, b"\0") + bytes(32))
            wait_until(lambda: auth.refused == 3, 5, "the third refusal")
            host, peer_port = raw.getsockname()
        assert f"refused a client from {host}:{peer_port}: it does not speak CURVE (a NULL or PLAIN client)" in caplog.text
        assert auth.decide([b"1.0", b"7", b"d", b"10.0.0.9", b"", b"NULL"])[2] == b"400"
        assert auth.decide([b"1.0", b"8", b"d", b"10.0.0.9", b"", b"CURVE", z85.decode(good_pub)])[2:5] == [
            b"200", b"OK", good_pub]
    finally:
        for s in [*socks, router]:
            s.close(0)
        auth.close()
        ctx.term()


def test_an_allow_list_without_keys_is_refused() -> None:
    ctx = zmq.Context()
    try:
        with pytest.raises(KeyFileError, match="no client key is allowed.*--allow"):
            CurveAllowList(ctx, [])
    finally:
        ctx.term()
