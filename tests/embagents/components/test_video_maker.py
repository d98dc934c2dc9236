"""VideoMessageMaker on real opencv: clips of motion by frame difference and by Farneback flow."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("cv2")

from embagents.components import VideoMakerConfig, VideoMessageMaker  # noqa: E402
from embagents.config import ConfigError  # noqa: E402
from embagents.msgs import Image, Video  # noqa: E402
from embagents.topic import Topic  # noqa: E402


def frame(x: int) -> Image:
    """A textured square at column ``x`` on a grey background (flow needs texture)."""
    img = np.full((96, 128, 3), 90, np.uint8)
    rng = np.random.default_rng(0)
    img[30:70, x:x + 40] = rng.integers(0, 255, (40, 40, 3), dtype=np.uint8)
    return Image(data=img, stamp=float(x))


def run(xs: list[int], **config: object) -> list[Video]:
    maker = VideoMessageMaker(name="clips", inputs=[Topic("cam", Image)], outputs=[Topic("clips", Video)],
                              config=VideoMakerConfig(**config))
    sent: list[Video] = []
    maker.attach(lambda topic, msg: sent.append(msg))
    for x in xs:
        maker.on_message("cam", frame(x))
        maker.execute()
    return sent


@pytest.mark.parametrize("method", ["difference", "optical_flow"])
def test_moving_frames_become_one_clip_and_still_frames_none(method: str) -> None:
    still, moving = [10] * 5, list(range(12, 60, 4))  # 12 moving frames
    clips = run(still + moving + [moving[-1]] * 5, method=method, min_frames=3)
    assert len(clips) == 1
    assert clips[0].frames.shape == (12, 96, 128, 3) and clips[0].stamps.tolist() == [float(x) for x in moving]


def test_a_long_motion_is_cut_at_max_frames_and_a_short_one_is_dropped() -> None:
    assert [len(c.frames) for c in run([10] + list(range(12, 90, 3)) + [87, 87], max_frames=10, min_frames=3)] == [10, 10, 6]
    assert run([10, 14, 18, 18, 18], min_frames=3) == []  # two moving frames: below min_frames


def test_the_threshold_is_a_percentage_of_changed_pixels() -> None:
    # The square covers 40 * 40 / (96 * 128) = 13 % of the image; a 4 px step changes about 2.6 %.
    assert run([10, 14, 18, 22, 22], threshold_percent=1.0, min_frames=1)
    assert not run([10, 14, 18, 22, 22], threshold_percent=20.0, min_frames=1)
    with pytest.raises(ConfigError, match="percentage"):
        VideoMakerConfig(threshold_percent=150)
