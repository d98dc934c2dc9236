"""The Camera: a source component that owns an opencv ``VideoCapture`` in its own process.

``source`` is a device index (``0``), a video file (``loop=True`` plays it
again from the start) or a network URL (rtsp://, http://). The trigger is
the frame rate in Hz (default 15 steps per second). Each step publishes one
frame as an RGB ``Image`` (through shared memory), resized to ``width`` x
``height`` when given. A device that cannot be opened, or is lost, is retried
with exponential backoff (``retry_s`` doubling up to ``retry_max_s``) and
reported on health as SYSTEM_FAILURE naming the source and the fix; the
process and the system keep running. A file that ends (without ``loop``)
sets ``finished``.

Example::

    >>> from embagents.msgs import Image
    >>> from embagents.topic import Topic
    >>> cam = Camera(name="cam", outputs=[Topic("image", Image)], config=CameraConfig(source="clip.mp4"), trigger=10.0)
    >>> cam.rate_hz
    10.0
"""

from __future__ import annotations

import os
import time
from typing import Any

from attrs import define, field

from embagents.components.component import Component
from embagents.components.device_retry import DeviceRetry
from embagents.config import BaseComponentConfig, ConfigError, positive_float, to_bool
from embagents.msgs import Image

__all__ = ["Camera", "CameraConfig"]


def _source(value: object) -> int | str:
    if isinstance(value, bool) or not isinstance(value, (int, str)) or value == "":
        raise ConfigError(f"source must be a device index (0), a video file path or a URL, got {value!r}")
    return int(value) if isinstance(value, str) and value.isdigit() else value


def _size(value: object) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ConfigError(f"width and height are pixels > 0 (or None), got {value!r}")
    return value


@define(kw_only=True)
class CameraConfig(BaseComponentConfig):
    """Settings of :class:`Camera` (see the module docstring).

    >>> CameraConfig(source="0").source
    0
    """

    source: int | str = field(default=0, converter=_source)
    loop: bool = field(default=False, converter=to_bool)
    width: int | None = field(default=None, converter=_size)
    height: int | None = field(default=None, converter=_size)
    frame_id: str = "camera"
    retry_s: float = field(default=0.5, converter=positive_float)
    retry_max_s: float = field(default=10.0, converter=positive_float)


class Camera(Component):
    """Publishes frames of a camera, file or stream (see the module docstring)."""

    allowed_inputs = {"Optional": []}
    allowed_outputs = {"Required": [Image]}
    config_class = CameraConfig

    def __init__(self, *, name: str, **kw: Any) -> None:
        self._cap: Any = None
        self._retry = DeviceRetry()
        self.frames = 0
        self.finished = False
        super().__init__(name=name, **kw)

    def default_trigger(self) -> float:
        return 15.0

    def _describe(self) -> str:
        src = self.config.source
        if isinstance(src, int):
            return f"camera device {src}"
        return f"video file {os.path.abspath(src)!r}" if "://" not in src else f"stream {src!r}"

    def _open(self) -> bool:
        import cv2

        src = self.config.source
        cap = cv2.VideoCapture(src)
        if isinstance(src, int) and cap.isOpened():
            if self.config.width:
                cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.config.width)
            if self.config.height:
                cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.config.height)
        if not cap.isOpened():
            cap.release()
            self._lost("cannot be opened")
            return False
        self._cap = cap
        self._retry.opened()
        self.logger.info("%s: opened %s", self._label(), self._describe())
        return True

    def _lost(self, what: str) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None
        delay = self._retry.failed(self.config.retry_s, self.config.retry_max_s)
        fix = ("check the index (ls /dev/video*) and that no other program holds it" if isinstance(self.config.source, int)
               else "check the path" if "://" not in str(self.config.source) else "check the URL and the network")
        self.set_system_failure(f"{self._describe()} {what}; {fix}; retrying in {delay:.1f} s")

    def _execution_step(self, **inputs: Any) -> None:
        import cv2

        if self.finished or (self._cap is None and (self._retry.waiting() or not self._open())):
            self._health_set_in_step = True  # the failure (or the end) stands between retries
            return
        ok, bgr = self._cap.read()
        if not ok and isinstance(self.config.source, str) and "://" not in self.config.source:
            if not self.config.loop:
                self.finished = True
                self.logger.info("%s: %s ended after %d frames", self._label(), self._describe(), self.frames)
                self._cap.release()
                self._cap = None
                self._health_set_in_step = True
                return
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, bgr = self._cap.read()
        if not ok:
            self._lost("stopped giving frames")
            return
        w, h = self.config.width, self.config.height
        if (w or h) and (bgr.shape[1], bgr.shape[0]) != (w or bgr.shape[1], h or bgr.shape[0]):
            bgr = cv2.resize(bgr, (w or bgr.shape[1], h or bgr.shape[0]), interpolation=cv2.INTER_AREA)
        self.frames += 1
        frame = Image(data=cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), encoding="rgb8", stamp=time.time(),
                      frame_id=self.config.frame_id)
        for t in self.outputs:
            self.publish(t, frame)

    def on_shutdown(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None
