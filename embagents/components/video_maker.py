"""VideoMessageMaker: frames in, clips of motion out, as :class:`~embagents.msgs.Video` messages.

Each frame is compared with the previous one, downscaled to ``analysis_width``
and grey: by absolute difference (``method="difference"``: a pixel changed
when it moved more than ``pixel_threshold`` levels) or by opencv's Farneback
optical flow (``method="optical_flow"``: a pixel moved more than
``flow_threshold`` pixels). A frame is *moving* when more than
``threshold_percent`` of its pixels changed. Moving frames are gathered into
a clip; the clip is published when motion stops (if it has at least
``min_frames``) or when it reaches ``max_frames``.

Example::

    >>> import numpy as np
    >>> from embagents.msgs import Image, Video
    >>> from embagents.topic import Topic
    >>> maker = VideoMessageMaker(name="clips", inputs=[Topic("cam", Image)], outputs=[Topic("clips", Video)],
    ...                           config=VideoMakerConfig(min_frames=2))
    >>> sent = []
    >>> maker.attach(lambda topic, msg: sent.append(msg))
    >>> for v in (0, 255, 0, 255, 255, 255):   # three moving frames, then stillness
    ...     _ = maker.on_message("cam", Image(data=np.full((48, 64, 3), v, np.uint8))) and maker.execute()
    >>> [clip.frames.shape for clip in sent]
    [(3, 48, 64, 3)]
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from attrs import define, field

from embagents.components.component import Component
from embagents.components.imaging import image_rgb
from embagents.config import (
    BaseComponentConfig,
    ConfigError,
    int_at_least,
    one_of,
    positive_float,
    positive_int,
)
from embagents.msgs import Image, Video
from embagents.topic import Topic

__all__ = ["VideoMakerConfig", "VideoMessageMaker", "motion_percent"]

METHODS = ("difference", "optical_flow")


def _percent(value: object) -> float:
    out = positive_float(value)
    if out > 100:
        raise ConfigError(f"threshold_percent is a percentage of pixels in (0, 100], got {value!r}")
    return out


def _method(value: object) -> str:
    return one_of("method", *METHODS)(value)


def _analysis_width(value: object) -> int:
    return int_at_least(8)(value)


@define(kw_only=True)
class VideoMakerConfig(BaseComponentConfig):
    """Settings of :class:`VideoMessageMaker` (see the module docstring).

    >>> VideoMakerConfig(method="optical_flow").method
    'optical_flow'
    """

    method: str = field(default="difference", converter=_method)
    threshold_percent: float = field(default=1.0, converter=_percent)
    pixel_threshold: int = field(default=25, converter=positive_int)
    flow_threshold: float = field(default=1.0, converter=positive_float)
    min_frames: int = field(default=5, converter=positive_int)
    max_frames: int = field(default=60, converter=positive_int)
    analysis_width: int = field(default=160, converter=_analysis_width)

    def __attrs_post_init__(self) -> None:
        if self.max_frames < self.min_frames:
            raise ConfigError(f"max_frames ({self.max_frames}) must be >= min_frames ({self.min_frames})")


def motion_percent(prev: np.ndarray, cur: np.ndarray, config: VideoMakerConfig) -> float:
    """Percent of pixels that changed between two grey frames of one size."""
    import cv2

    if config.method == "difference":
        changed = cv2.absdiff(prev, cur) > config.pixel_threshold
    else:
        flow = cv2.calcOpticalFlowFarneback(prev, cur, None, 0.5, 3, 15, 3, 5, 1.2, 0)  # type: ignore[call-overload]  # OpenCV's stubs omit that flow may be None (it allocates one)
        changed = np.hypot(flow[..., 0], flow[..., 1]) > config.flow_threshold
    return 100.0 * float(np.count_nonzero(changed)) / changed.size


class VideoMessageMaker(Component):
    """Cuts a stream of images into clips of motion (see the module docstring)."""

    allowed_inputs = {"Required": [Image]}
    allowed_outputs = {"Required": [Video]}
    config_class = VideoMakerConfig

    def __init__(self, *, name: str, **kw: Any) -> None:
        self._prev: np.ndarray | None = None
        self._frames: list[np.ndarray] = []
        self._stamps: list[float] = []
        self.last_motion = 0.0
        super().__init__(name=name, **kw)

    def default_trigger(self) -> Topic | None:
        return self.inputs[0] if self.inputs else None

    def _grey(self, rgb: np.ndarray) -> np.ndarray:
        import cv2

        h, w = rgb.shape[:2]
        width = min(self.config.analysis_width, w)
        small = cv2.resize(rgb, (width, max(1, round(h * width / w))), interpolation=cv2.INTER_AREA)
        return cv2.cvtColor(small, cv2.COLOR_RGB2GRAY)

    def _execution_step(self, **inputs: Any) -> None:
        msg = inputs[self.inputs[0].name]
        rgb = image_rgb(msg)
        grey = self._grey(rgb)
        prev, self._prev = self._prev, grey
        if prev is None or prev.shape != grey.shape:
            return
        self.last_motion = motion_percent(prev, grey, self.config)
        if self.last_motion > self.config.threshold_percent:
            self._frames.append(np.array(rgb))  # a copy: the received frame's memory is the sender's
            self._stamps.append(msg.stamp or time.time())
            if len(self._frames) >= self.config.max_frames:
                self.flush()
        elif self._frames:
            self.flush()

    def flush(self) -> bool:
        """Publish the clip gathered so far if it has ``min_frames``; True if one went out."""
        frames, stamps = self._frames, self._stamps
        self._frames, self._stamps = [], []
        if len(frames) < self.config.min_frames:
            return False
        clip = Video(frames=np.stack(frames), stamps=np.array(stamps), encoding="rgb8",
                     frame_id=self.inputs[0].name)
        for t in self.outputs:
            self.publish(t, clip)
        return True
