from __future__ import annotations

import os
import struct

import attrs
import msgpack
import numpy as np
import pytest

from actors.codec import EXT_FLAT, EXT_MESSAGE, MAX_EXT_DEPTH, Codec, Flat, message
from actors.errors import CodecError, CorruptFrame, MessageTooLarge, StaleFrame, UnregisteredType
from actors.shm import ShmPool, ShmReader


@message("test/Point")
@attrs.define
class Point:
    x: float
    tags: list[str] = attrs.field(factory=list)
    arr: np.ndarray | None = None


class NotRegistered:
    pass


_SAMPLE = struct.Struct("<dI")


def _unpack_sample(b: memoryview) -> Sample:
    value, count = _SAMPLE.unpack_from(b)
    return Sample(value, count, str(b[_SAMPLE.size:], "utf-8"))


@message("test/Sample", flat=(lambda s: _SAMPLE.pack(s.value, s.count) + s.name.encode(), _unpack_sample))
@attrs.define
class Sample:
    value: float
    count: int
    name: str = ""


def test_a_class_with_a_flat_form_crosses_as_those_bytes_alone_and_in_other_data() -> None:
    c = Codec()
    data = c.encode(Sample(1.5, 7, "imu"))[0]
    assert data[0] == 0xC7 and data[2] == EXT_FLAT and data.endswith(_SAMPLE.pack(1.5, 7) + b"imu")  # no map of fields
    assert c.decode(data) == Sample(1.5, 7, "imu")
    assert c.decode(memoryview(b"\0" + data)[1:]) == Sample(1.5, 7, "imu")  # as a topic's frame comes
    long = Sample(2.0, 1, "x" * 70_000)  # ext 32: read by the unpacker
    assert c.decode(c.encode({"s": [long, Point(1.0)]})[0]) == {"s": [long, Point(1.0)]}
    assert c.decode(c.encode(Sample(0.0, 0, "y" * 300))[0]).name == "y" * 300  # ext 16


def test_a_flat_object_encodes_as_the_message_without_building_it() -> None:
    c = Codec()
    flat = Flat(Sample, _SAMPLE.pack(3.0, 2) + b"cam")
    assert flat.frame() == c.encode(flat)[0] == c.encode(Sample(3.0, 2, "cam"))[0]
    assert c.decode(flat.frame()) == flat.message() == Sample(3.0, 2, "cam")
    with pytest.raises(TypeError, match="Point has no flat form: register it with flat="):
        Flat(Point, b"")


@pytest.mark.parametrize("cut", [1, 2, 3, 5, 12, 20])
def test_a_flat_message_cut_short_is_a_corrupt_frame(cut: int) -> None:
    data = Codec().encode(Sample(1.0, 1, "abc"))[0]
    with pytest.raises(CorruptFrame):
        Codec().decode(data[:cut])
    with pytest.raises(CorruptFrame):
        Codec().decode(data[:2] + bytes([EXT_FLAT]) + b"\x0btest/Sample" + b"\xff" * 20)  # not UTF-8


def test_round_trip_of_native_values_messages_and_arrays() -> None:
    c = Codec()
    a = np.arange(12, dtype=np.float32).reshape(3, 4)
    data, segs = c.encode({"p": Point(1.5, ["a"], a), "b": b"\x00\x01", "n": [1, None, True]})
    out = c.decode(data)
    assert segs == []
    assert out["p"].x == 1.5 and out["p"].tags == ["a"]
    assert out["p"].arr.dtype == np.float32 and (out["p"].arr == a).all()
    assert out["b"] == b"\x00\x01" and out["n"] == [1, None, True]


def test_unregistered_type_names_the_class_and_the_fix() -> None:
    with pytest.raises(UnregisteredType, match=r"NotRegistered.*@actors.message"):
        Codec().encode(NotRegistered())


def test_messages_inside_messages_round_trip_after_a_frame_that_failed_deep_inside() -> None:
    # Payloads are packed by reused packers, one per depth: a message inside a message needs its own,
    # and a failure two levels down must leave every one of them empty for the next frame.
    c = Codec()
    with pytest.raises(UnregisteredType, match="NotRegistered"):
        c.encode({"p": Point(2.0, ["x"], np.zeros(3)), "q": [Point(3.0, [NotRegistered()])]})  # type: ignore[list-item]
    inner = Point(4.0, ["y"], np.arange(3, dtype=np.int16))
    out = c.decode(c.encode({"outer": Point(5.0, [], None), "deep": [inner, {"again": Point(6.0, [], inner)}]})[0])
    assert out["outer"] == Point(5.0, [], None)
    for p in (out["deep"][0], out["deep"][1]["again"].arr):
        assert p.x == 4.0 and p.tags == ["y"] and p.arr.tolist() == [0, 1, 2] and p.arr.dtype == np.int16


def nested_message(levels: int) -> msgpack.ExtType:
    """``levels`` messages, each one a field of the last, as their extension (a frame's body)."""
    data = msgpack.packb(["test/Point", {"x": 1.0}])
    for _ in range(levels - 1):
        data = msgpack.packb(["test/Point", {"x": msgpack.ExtType(EXT_MESSAGE, data)}])
    return msgpack.ExtType(EXT_MESSAGE, data)


def nested_frame(levels: int) -> bytes:
    return msgpack.packb(nested_message(levels))


@pytest.mark.parametrize("levels", [200, 10_000])
def test_deeply_nested_messages_are_a_corrupt_frame_not_a_crash(levels: int) -> None:
    # Each level used to be one more msgpack unpacker on the C stack: 200 levels were a SIGSEGV.
    with pytest.raises(CorruptFrame, match=f"nested more than {MAX_EXT_DEPTH} deep"):
        Codec().decode(nested_frame(levels))
    with pytest.raises(CorruptFrame, match=f"nested more than {MAX_EXT_DEPTH} deep"):
        Codec().peek(nested_frame(levels))


def test_nesting_up_to_the_limit_round_trips_and_beyond_it_is_refused_when_encoding() -> None:
    c = Codec()
    deep = c.decode(nested_frame(MAX_EXT_DEPTH))
    for _ in range(MAX_EXT_DEPTH - 1):
        deep = deep.x
    assert deep == Point(1.0)
    p = Point(1.0)
    for _ in range(MAX_EXT_DEPTH):
        p = Point(p)  # type: ignore[arg-type]
    with pytest.raises(CodecError, match=f"nest more than {MAX_EXT_DEPTH} deep"):
        c.encode(p)
    assert c.decode(c.encode(Point(2.0))[0]) == Point(2.0)  # the packers were left empty


def test_ten_thousand_nested_arrays_are_a_corrupt_frame() -> None:
    with pytest.raises(CorruptFrame):
        Codec().decode(b"\x91" * 10_000 + b"\xc0")


def test_a_corrupt_frame_quotes_what_it_got_briefly() -> None:
    c = Codec()
    for body in (["n" * 1_000_000, {}], ["test/Point", {"k" * 1_000_000: 1}]):  # a huge name, a huge field
        with pytest.raises(CodecError) as err:
            c.decode(msgpack.packb(msgpack.ExtType(EXT_MESSAGE, msgpack.packb(body))))
        assert len(str(err.value)) < 500


def test_object_arrays_are_refused() -> None:
    with pytest.raises(UnregisteredType, match="dtype object"):
        Codec().encode(np.array([object()], dtype=object))


def test_oversize_frame_is_refused_with_sizes() -> None:
    c = Codec(max_frame_bytes=1000)
    with pytest.raises(MessageTooLarge, match="exceeds the limit of 1000 bytes"):
        c.encode(b"x" * 2000)


@pytest.mark.parametrize(
    "garbage",
    [b"\xc1", b"\x92\x01", msgpack.packb(msgpack.ExtType(99, b"zz")), msgpack.packb(msgpack.ExtType(2, b"\x01"))],
)
def test_garbage_is_a_corrupt_frame(garbage: bytes) -> None:
    with pytest.raises(CorruptFrame):
        Codec().decode(garbage)


def test_unknown_message_name_says_what_to_import() -> None:
    frame = msgpack.packb(msgpack.ExtType(2, msgpack.packb(["nobody/Knows", {}])))
    with pytest.raises(UnregisteredType, match="nobody/Knows"):
        Codec().decode(frame)


def test_a_frame_cannot_run_code() -> None:
    # A pickle payload is just bytes to us: it is never unpickled.
    import pickle  # noqa: S403 - building a hostile frame on purpose

    evil = pickle.dumps(print)
    with pytest.raises(CorruptFrame):
        Codec().decode(evil)


def test_a_forwarded_topic_frame_goes_on_as_its_handle_and_is_not_copied() -> None:
    camera, vision = ShmPool(f"eatest{os.getpid()}_7_"), ShmPool(f"eatest{os.getpid()}_8_")
    try:
        codec = Codec(vision, ShmReader(pool=vision))
        frame_out, _ = Codec().encode({"image": np.zeros((1080, 1920, 3), np.uint8)},
                                      sink=_RingOf(camera))  # as the camera publishes it
        frame = codec.decode(frame_out)["image"]  # as Vision's subscription receives it
        mapped: list[list[object]] = []
        data, segments = codec.encode({"image": frame}, forward=True)
        assert segments == [] and vision.segment_count == 0  # Vision wrote nothing
        assert Codec(source=ShmReader()).decode(data, mapped=mapped)["image"].shape == (1080, 1920, 3)
        assert mapped[0][0].startswith(camera.prefix)  # the detector maps the camera's own segment
        _, copied = codec.encode({"image": frame})  # without forward: copied, as before
        assert len(copied) == 1 and vision.segment_count == 1
        del frame
    finally:
        camera.close()
        vision.close()


class _RingOf:
    def __init__(self, pool: ShmPool) -> None:
        self.pool = pool

    def put(self, arr: np.ndarray) -> list[object]:
        return self.pool.put_ring("cam", arr)


def test_peek_names_a_frame_whose_shared_memory_is_gone() -> None:
    pool = ShmPool(f"eatest{os.getpid()}_9_")
    data, _ = Codec(pool).encode({"id": 7, "a": np.zeros(70_000, np.uint8)})
    pool.close()  # the writer is gone
    with pytest.raises(StaleFrame):
        Codec(source=ShmReader()).decode(data)
    assert Codec().peek(data) == {"id": 7, "a": None}
