"""A mailbox survives any frame any local process sends to its socket (logged and dropped)."""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from typing import Any

import msgpack
import pytest
import zmq
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from actors import ActorSystem, wire
from actors.codec import EXT_MESSAGE, EXT_NDARRAY, EXT_SHM
from tests.actors.test_codec import nested_message
from tests.actors.workers import Echo


@pytest.fixture(scope="module")
def echo_system() -> Iterator[ActorSystem]:
    s = ActorSystem()
    try:
        yield s
    finally:
        s.shutdown()


def _raw(system: ActorSystem, name: str) -> zmq.Socket:
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(system.rt.endpoint(name))
    return sock


def _alive(system: ActorSystem, name: str, pid: int) -> None:
    """The same incarnation still answers (an actor that crashed would not have this pid)."""
    assert system.ref(name).ask("pid", timeout=5).get() == pid


@pytest.mark.parametrize("frame", [
    [wire.TELL, 0, "zero"],
    [wire.TELL, -5, "negative"],
    [wire.TELL, 1 << 63, "too large"],
    [wire.TELL, True, "a bool is not a sequence number"],
    [wire.ASK, "1", "a string seq"],
    [wire.RELEASE, 7],
    [wire.RELEASE, None],
    [wire.RELEASE, [1, 2]],
    [wire.TELL, 3],
    [wire.REPLY, 1, True, None],
    [],
    {"kind": 0},
    "text",
])
def test_a_malformed_frame_is_dropped_and_the_actor_goes_on(echo_system: ActorSystem, frame: Any) -> None:
    ref = echo_system.ref("fuzz") if _spawned(echo_system) else echo_system.spawn(Echo, "fuzz")
    pid = ref.ask("pid", timeout=5).get()
    sock = _raw(echo_system, "fuzz")
    try:
        sock.send(msgpack.packb(frame))
        _alive(echo_system, "fuzz", pid)
    finally:
        sock.close()


@pytest.mark.parametrize("levels", [200, 10_000])
def test_a_frame_of_deeply_nested_messages_is_dropped_and_the_actor_goes_on(echo_system: ActorSystem, levels: int) -> None:
    ref = echo_system.ref("fuzz") if _spawned(echo_system) else echo_system.spawn(Echo, "fuzz")
    pid = ref.ask("pid", timeout=5).get()
    dropped = echo_system.ctrl("fuzz", "stats")["dropped"]
    sock = _raw(echo_system, "fuzz")
    try:
        for kind in (wire.TELL, wire.ASK):  # 200 levels of these used to kill the actor with SIGSEGV
            sock.send(msgpack.packb([kind, 1 << 40, nested_message(levels)]))
        _alive(echo_system, "fuzz", pid)
        # The raw socket is a connection of its own: ZeroMQ queues it fairly beside the system's, so the
        # "pid" ask may be answered before both frames were read. Read until they are, then no more.
        deadline = time.monotonic() + 5
        while echo_system.ctrl("fuzz", "stats")["dropped"] < dropped + 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert echo_system.ctrl("fuzz", "stats")["dropped"] == dropped + 2
        _alive(echo_system, "fuzz", pid)
    finally:
        sock.close()


_scalars = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-(1 << 63), max_value=(1 << 64) - 1),
    st.floats(allow_nan=True), st.text(max_size=20).filter(lambda t: t != "raise"), st.binary(max_size=40),
)
_values = st.recursive(_scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.one_of(st.text(max_size=5), st.integers(-1000, 1000)), inner, max_size=4),
), max_leaves=12)
_shm_names = st.one_of(st.text(max_size=30), st.sampled_from(["../../etc/passwd", "/dev/zero", "eaX_1_1", "ea00_1_1"]))
_ext = st.one_of(
    st.builds(msgpack.ExtType, st.integers(0, 127), st.binary(max_size=40)),
    st.builds(lambda n, g, o, d, s: msgpack.ExtType(EXT_SHM, msgpack.packb([n, g, o, d, s])),
              _shm_names, st.integers(-2, 5), st.integers(-10, 1 << 20), st.sampled_from(["<u1", "|O", "x", "<f8"]),
              st.lists(st.integers(-3, 1 << 20), max_size=3)),
    st.builds(lambda d, s, b: msgpack.ExtType(EXT_NDARRAY, msgpack.packb([d, s, b])),
              st.sampled_from(["<u1", "|O", "<f8", "zz"]), st.lists(st.integers(-3, 50), max_size=3), st.binary(max_size=64)),
    st.builds(lambda w, f: msgpack.ExtType(EXT_MESSAGE, msgpack.packb([w, f])),
              st.sampled_from(["embagents/String", "nope", ""]), st.dictionaries(st.text(max_size=5), _scalars, max_size=3)),
)
_kinds = st.one_of(st.sampled_from([wire.TELL, wire.ASK, wire.CTRL, wire.RELEASE]), st.integers(-2, 10), _scalars)
#: Frames from the wire grammar (see actors.wire) and its near misses, plus raw bytes.
_frames = st.one_of(
    st.builds(lambda k, q, b: msgpack.packb([k, q, b]), _kinds, st.one_of(st.integers(-3, 50), _scalars), st.one_of(_values, _ext)),
    st.builds(lambda q, b: msgpack.packb([wire.RELEASE, q, *b]), st.one_of(_values, st.lists(_shm_names, max_size=3)),
              st.lists(_values, max_size=2)),
    st.builds(lambda v: msgpack.packb(v), st.one_of(_values, st.lists(_values, min_size=0, max_size=6))),
    st.binary(max_size=64),
)


def _stops_it(frame: bytes) -> bool:
    """A well-formed control 'stop' is a real request, not garbage."""
    try:
        msg = msgpack.unpackb(frame, strict_map_key=False)
    except Exception:
        return False
    return (isinstance(msg, list) and len(msg) == 3 and msg[0] == wire.CTRL
            and isinstance(msg[2], list) and bool(msg[2]) and msg[2][0] == "stop")


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(batch=st.lists(st.one_of(_frames, st.lists(st.binary(max_size=16), min_size=2, max_size=3)), min_size=1, max_size=8))
def test_fuzzed_frames_never_take_an_actor_down(echo_system: ActorSystem, batch: list[Any]) -> None:
    ref = echo_system.ref("fuzz") if _spawned(echo_system) else echo_system.spawn(Echo, "fuzz")
    pid = ref.ask("pid", timeout=5).get()
    sock = _raw(echo_system, "fuzz")
    try:
        for frame in batch:
            if isinstance(frame, list):
                sock.send_multipart(frame)  # the wrong number of parts
            elif not _stops_it(frame):
                sock.send(frame)
        _alive(echo_system, "fuzz", pid)
    finally:
        sock.close()


def _spawned(system: ActorSystem) -> bool:
    return os.path.exists(system.rt.endpoint("fuzz")[len("ipc://"):])
