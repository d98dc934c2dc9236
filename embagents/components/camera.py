"""The Camera: a source component that owns an opencv ``VideoCapture`` in its own process.

``source`` is a device index (``0``), a video file (``loop=True`` plays it
again from the start), a network URL (rtsp://, http://), or still images: an
image file, a folder of them or a glob (``"photos/*.jpg"``), played in name
order, one per step (``loop=True``: again from the first; else once). The trigger is
the frame rate in Hz (default 15 steps per second). Each step publishes one
frame as an RGB ``Image`` (through shared memory), resized to ``width`` x
``height`` when given. A device that cannot be opened, or is lost, is retried
with exponential backoff (``retry_s`` doubling up to ``retry_max_s``) and
reported on health as SYSTEM_FAILURE naming the source and the fix; the
process and the system keep running. A file (or the images) that ends
(without ``loop``) sets ``finished``. An image that cannot be read is skipped,
with a warning naming it.

Example::

    >>> from embagents.msgs import Image
    >>> from embagents.topic import Topic
    >>> cam = Camera(name="cam", outputs=[Topic("image", Image)], config=CameraConfig(source="clip.mp4"), trigger=10.0)
    >>> cam.rate_hz
    10.0
    >>> is_image_source("photos/*.jpg"), is_image_source("clip.mp4")
    (True, False)
"""

from __future__ import annotations

import glob
import os
import time
from typing import Any

from attrs import define, field

from embagents.components.component import Component
from embagents.components.device_retry import DeviceRetry
from embagents.config import BaseComponentConfig, ConfigError, positive_float, to_bool
from embagents.msgs import Image

__all__ = ["IMAGE_EXTENSIONS", "Camera", "CameraConfig", "is_image_source"]

#: File name endings a source of still images may have (what opencv's imread reads).
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm", ".pbm")


def is_image_source(source: int | str) -> bool:
    """Whether ``source`` names still images: an image file, a folder or a glob (not a video, device or URL)."""
    if not isinstance(source, str) or "://" in source:
        return False
    return source.lower().endswith(IMAGE_EXTENSIONS) or glob.has_magic(source) or os.path.isdir(source)


def _image_files(source: str) -> list[str]:
    if os.path.isdir(source):
        names = [os.path.join(source, n) for n in os.listdir(source)]
    elif glob.has_magic(source):
        names = glob.glob(source)
    else:
        names = [source]
    return sorted(n for n in names if os.path.isfile(n) and n.lower().endswith(IMAGE_EXTENSIONS))


def _source(value: object) -> int | str:
    if isinstance(value, bool) or not isinstance(value, (int, str)) or value == "":
        raise ConfigError(f"source must be a device index (0), a video file, a URL, or an image file, folder "
                          f"or glob, got {value!r}")
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
        self._images: list[str] | None = None  # still images: the files, in order, and the next one's index
        self._next_image = 0
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
        if is_image_source(src):
            kind = "image folder" if os.path.isdir(src) else "images matching" if glob.has_magic(src) else "image file"
            return f"{kind} {os.path.abspath(src)!r}"
        return f"video file {os.path.abspath(src)!r}" if "://" not in src else f"stream {src!r}"

    def _open(self) -> bool:
        import cv2

        src = self.config.source
        if is_image_source(src):
            return self._open_images(str(src))
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

    def _open_images(self, src: str) -> bool:
        files = _image_files(src)
        if not files:
            many = os.path.isdir(src) or glob.has_magic(src)
            self._lost(f"holds no images ({', '.join(e[1:] for e in IMAGE_EXTENSIONS[:4])}, ...)" if many
                       else "cannot be opened")
            return False
        self._images, self._next_image = files, 0
        self._retry.opened()
        self.logger.info("%s: playing %d images of %s", self._label(), len(files), self._describe())
        return True

    def _read_image(self) -> Any:
        """The next still image as BGR, or ``None`` at the end; unreadable files are skipped."""
        import cv2

        assert self._images is not None
        for _ in range(len(self._images)):
            if self._next_image >= len(self._images):
                if not self.config.loop:
                    return None
                self._next_image = 0
            path = self._images[self._next_image]
            self._next_image += 1
            bgr = cv2.imread(path, cv2.IMREAD_COLOR)
            if bgr is not None:
                return bgr
            self.logger.warning("%s: %s is not an image opencv can read; skipped", self._label(), path)
        return None

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

        if self.finished or (self._cap is None and self._images is None and
                             (self._retry.waiting() or not self._open())):
            self._health_set_in_step = True  # the failure (or the end) stands between retries
            return
        if self._images is not None:
            bgr = self._read_image()
            if bgr is None:
                self.finished = True
                self.logger.info("%s: %s ended after %d frames", self._label(), self._describe(), self.frames)
                self._health_set_in_step = True
                return
            self._publish(bgr)
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
        self._publish(bgr)

    def _publish(self, bgr: Any) -> None:
        import cv2

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
