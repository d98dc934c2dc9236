"""The bridge's payloads: large arrays out of band after the msgpack body; a forged handle is a corrupt frame."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

import embagents.msgs  # noqa: F401 - registers Image
from actors.codec import Codec
from actors.errors import CorruptFrame
from embagents.msgs import Image
from embagents.zenoh.bridge_actor import (
    _HEAD,
    MAGIC,
    MAX_PAYLOAD,
    _Blobs,
    _Delivered,
    _from_jpeg,
    _to_jpeg,
    _unlz4,
)


def _roundtrip(msg: object) -> object:
    blobs = _Blobs()
    codec = Codec(source=blobs)
    body, _ = codec.encode(msg, sink=blobs)
    data = bytes(blobs.frame(body))
    return Codec(source=blobs).decode(blobs.split(data))


def test_a_1080p_image_crosses_with_its_pixels_after_the_body_and_small_arrays_inline() -> None:
    frame = (np.arange(1080 * 1920 * 3) % 251).astype(np.uint8).reshape(1080, 1920, 3)
    out = _roundtrip(Image(data=frame[:, ::2], stamp=1.5, frame_id="cam"))  # not contiguous: copied once
    assert isinstance(out, Image) and out.frame_id == "cam" and out.stamp == 1.5
    assert np.array_equal(out.data, frame[:, ::2])
    small = _roundtrip({"a": np.arange(10, dtype=np.float32), "b": [np.zeros((300, 300), np.uint16)]})
    assert np.array_equal(small["a"], np.arange(10, dtype=np.float32))  # type: ignore[index]
    assert small["b"][0].shape == (300, 300)  # type: ignore[index]


@pytest.mark.parametrize("handle", [[0, 10**9, "|u1", [10**9]], [-8, 8, "|u1", [8]], [0, 8, "|O", [1]],
                                    [0, 9, "<u2", [4]], ["x"]])
def test_a_forged_array_handle_is_a_corrupt_frame_not_a_crash(handle: list) -> None:
    import msgpack

    body = msgpack.packb(msgpack.ExtType(3, msgpack.packb(handle)))
    data = _HEAD.pack(MAGIC, len(body), 0) + body + bytes(16)
    blobs = _Blobs()
    with pytest.raises(CorruptFrame):
        Codec(source=blobs).decode(blobs.split(data))


def test_a_payload_that_is_not_ours_is_a_corrupt_frame() -> None:
    blobs = _Blobs()
    for data in (b"", b"hello world!", _HEAD.pack(MAGIC, 10**6, 0) + b"x"):
        with pytest.raises(CorruptFrame):
            blobs.split(data)


def test_a_frame_of_an_older_bridge_names_the_version_mismatch() -> None:
    old = struct.pack("<4sI", b"EZ1\0", 3) + b"abc" + bytes(8)
    with pytest.raises(CorruptFrame, match="another embagents version.*same embagents version"):
        _Blobs().split(old)
    # This version's own formats are not taken for another version's.
    jpeg = struct.pack("<4sIQ", b"EZJ\0", 3, 0) + b"abc"
    assert bytes(_Blobs().split(jpeg)) == b"abc"


def test_jpeg_brings_an_image_back_as_an_image_and_refuses_what_it_cannot_carry() -> None:
    pytest.importorskip("cv2")
    from skimage import data

    photo = data.astronaut()
    back = _from_jpeg(_roundtrip(_to_jpeg(Image(data=photo, encoding="rgb8", stamp=2.0, frame_id="cam"), 90)))
    assert isinstance(back, Image) and back.encoding == "rgb8" and back.frame_id == "cam" and back.stamp == 2.0
    assert back.data.shape == photo.shape and np.abs(back.data.astype(int) - photo).mean() < 4  # lossy, close
    with pytest.raises(ValueError, match="use compress='lz4' for other messages"):
        _to_jpeg(Image(data=np.zeros((4, 4), np.float32), encoding="32FC1"), 90)


def test_an_lz4_bomb_or_garbage_is_a_corrupt_frame() -> None:
    import lz4.frame

    assert _unlz4(lz4.frame.compress(b"abc" * 1000)) == b"abc" * 1000
    with pytest.raises(CorruptFrame, match="larger than"):
        _unlz4(lz4.frame.compress(bytes(MAX_PAYLOAD + 1)))
    with pytest.raises(CorruptFrame):
        _unlz4(b"not lz4 at all")


def test_what_a_killed_bridge_forwarded_is_known_to_its_successor_and_old_sources_make_room(tmp_path: Path) -> None:
    path = f"{tmp_path}/zenoh/_zenoh_bridge.delivered"
    first = _Delivered(path, slots=2)
    first.forwarded((b"zid-a", 1), 41)
    first.forwarded((b"zid-a", 1), 42)
    first.forwarded((b"zid-b", 7), 5)
    del first  # killed: nothing flushed by hand
    again = _Delivered(path, slots=2)
    assert again.seen((b"zid-a", 1), 42) and not again.seen((b"zid-a", 1), 43)
    assert again.seen((b"zid-b", 7), 5) and not again.seen((b"zid-c", 1), 1)
    again.forwarded((b"zid-c", 1), 1)  # a third source takes the least recently used slot (zid-a's)
    assert again.seen((b"zid-c", 1), 1) and again.seen((b"zid-b", 7), 5) and not again.seen((b"zid-a", 1), 42)
