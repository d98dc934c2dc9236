"""The bridge's payloads: large arrays out of band after the msgpack body; a forged handle is a corrupt frame."""

from __future__ import annotations

import numpy as np
import pytest

import embagents.msgs  # noqa: F401 - registers Image
from actors.codec import Codec
from actors.errors import CorruptFrame
from embagents.msgs import Image
from embagents.zenoh.bridge_actor import _HEAD, MAGIC, _Blobs


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
    data = _HEAD.pack(MAGIC, len(body)) + body + bytes(16)
    blobs = _Blobs()
    with pytest.raises(CorruptFrame):
        Codec(source=blobs).decode(blobs.split(data))


def test_a_payload_that_is_not_ours_is_a_corrupt_frame() -> None:
    blobs = _Blobs()
    for data in (b"", b"hello world!", _HEAD.pack(MAGIC, 10**6) + b"x"):
        with pytest.raises(CorruptFrame):
            blobs.split(data)
