"""The Vision component: images in, detections (and tracks, and an annotated image) out.

Each new ``Image`` or ``CompressedImage`` goes to the detector's model actor
(:class:`~embagents.models.DetectorModel` behind a
:class:`~embagents.models.LocalModelClient`): a camera frame crosses as the
camera wrote it, in the camera's shared memory, never copied. If the camera
reuses that frame's memory before the detector is done (its topic ring came
round), the answer is dropped with the frame and counted (``stale_frames``). The answer is published as :class:`~embagents.msgs.Detections`; with
tracking on (``enable_tracking`` or the ``track(label)`` action), as
:class:`~embagents.msgs.Trackings` too, ids kept over frames by ByteTrack
(from ``supervision``); with ``enable_visualization``, as an ``Image`` with
the boxes drawn. Actions (callable from events and ``embagents``' Call):
``take_picture()`` saves the current frame, ``record_video(seconds)`` writes
the next seconds as an mp4, ``track(label)`` tracks a label.

Example::

    >>> from embagents.msgs import Detections, Image
    >>> from embagents.models import DetectorModel, LocalModelClient
    >>> from embagents.topic import Topic
    >>> faces = DetectorModel(name="faces", family="mtcnn")
    >>> vision = Vision(name="vision", inputs=[Topic("camera", Image)], outputs=[Topic("faces", Detections)],
    ...                 model_client=LocalModelClient(faces), config=VisionConfig(threshold=0.9))
    >>> vision.trigger.name
    'camera'
"""

from __future__ import annotations

import os
import time
import warnings
from typing import Any

import numpy as np
from attrs import define, field

from embagents.components.imaging import annotate, image_rgb
from embagents.components.model_component import ModelComponent
from embagents.config import BaseComponentConfig, ConfigError, to_bool
from embagents.models.protocol import StaleInput
from embagents.msgs import CompressedImage, Detections, Image, Trackings
from embagents.topic import Topic

__all__ = ["Vision", "VisionConfig"]


def _threshold(value: object) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise ConfigError(f"threshold must be a number in [0, 1] or None, got {value!r}")
    try:
        out = float(value)
    except ValueError:
        raise ConfigError(f"threshold must be a number in [0, 1] or None, got {value!r}") from None
    if not 0.0 <= out <= 1.0:
        raise ConfigError(f"threshold must be a number in [0, 1] or None, got {value!r}")
    return out


def _labels(value: object) -> list[str]:
    items = [value] if isinstance(value, str) else list(value)  # type: ignore[call-overload]
    if not all(isinstance(s, str) and s for s in items):
        raise ConfigError(f"track_labels must be a list of label names, got {value!r}")
    return items


@define(kw_only=True)
class VisionConfig(BaseComponentConfig):
    """Settings of :class:`Vision`.

    - ``threshold``: minimum score (None: the model's own); input size and
      class names are the model's (:class:`~embagents.models.DetectorModel`).
    - ``enable_tracking``: publish Trackings; ``track_labels``: the labels
      tracked (empty: every label).
    - ``enable_visualization``: publish the annotated image on the Image output.
    - ``media_dir``: where pictures and videos are written.
    - ``video_fps``: frame rate written in recorded mp4 files.

    >>> VisionConfig(track_labels="person").track_labels
    ['person']
    """

    threshold: float | None = field(default=None, converter=_threshold)
    enable_tracking: bool = field(default=False, converter=to_bool)
    track_labels: list[str] = field(factory=list, converter=_labels)
    enable_visualization: bool = field(default=False, converter=to_bool)
    media_dir: str = field(default="vision_media")
    video_fps: float = field(default=10.0, converter=float)


class Vision(ModelComponent):
    """Detects objects in images with a detector model (see the module docstring)."""

    allowed_inputs = {"Required": [[Image, CompressedImage]]}
    allowed_outputs = {"Required": [Detections], "Optional": [Trackings, Image]}
    config_class = VisionConfig
    client_methods = ("detect",)
    client_task = "detect"
    client_fix = "LocalModelClient(DetectorModel(...))"
    #: The actions :func:`~embagents.components.llm_tools.register_tools_on` offers an LLM.
    llm_tools = ("take_picture",)

    def __init__(self, *, name: str, **kw: Any) -> None:
        self._frame: np.ndarray | None = None
        self._tracker: Any = None
        self._writer: Any = None
        self._record_until = 0.0
        self._media_count = 0
        self.stale_frames = 0  # frames the camera overwrote before their detection was done: dropped
        super().__init__(name=name, **kw)

    def default_trigger(self) -> Topic | None:
        return self.inputs[0] if self.inputs else None

    def run_warmup(self) -> None:
        self.model_client.detect(np.zeros((64, 64, 3), np.uint8))

    # --- steps ------------------------------------------------------------------------------
    def _execution_step(self, **inputs: Any) -> None:
        topic = next((t for t in self.inputs if t.name in self.fresh_inputs and inputs.get(t.name) is not None), None)
        if topic is None:
            return
        msg = inputs[topic.name]
        rgb = image_rgb(msg)
        self._frame = rgb
        options = {} if self.config.threshold is None else {"threshold": self.config.threshold}
        try:
            found = self.model_client.detect(rgb, **options)
        except StaleInput as exc:  # sensor data: the next frame is on its way
            self.stale_frames += 1
            self.logger.debug("%s: dropped a frame: %s", self._label(), exc)
            return
        h, w = rgb.shape[:2]
        det = Detections(boxes=found["boxes"], labels=list(found["labels"]), scores=found["scores"],
                         image_width=w, image_height=h, stamp=msg.stamp, frame_id=msg.frame_id)
        for t in self.outputs:
            if t.msg_type is Detections:
                self.publish(t, det)
        ids = self._track(det) if self.config.enable_tracking else None
        if self.config.enable_visualization or self._writer is not None:
            drawn = annotate(rgb, det.boxes, det.labels, det.scores)
            if self.config.enable_visualization:
                for t in self.outputs:
                    if t.msg_type is Image:
                        self.publish(t, Image(data=drawn, encoding="rgb8", stamp=msg.stamp, frame_id=msg.frame_id))
            self._record(drawn)
        if ids is not None:
            for t in self.outputs:
                if t.msg_type is Trackings:
                    self.publish(t, ids)

    def _track(self, det: Detections) -> Trackings:
        import supervision as sv

        if self._tracker is None:
            with warnings.catch_warnings():  # deprecated in 0.28 for Roboflow's `trackers`, which needs
                warnings.simplefilter("ignore", FutureWarning)  # the non-headless opencv-python
                self._tracker = sv.ByteTrack(frame_rate=int(self.rate_hz or self.config.video_fps))
        wanted = self.config.track_labels
        keep = [i for i, label in enumerate(det.labels) if not wanted or label in wanted]
        names = sorted(set(det.labels))
        tracked = self._tracker.update_with_detections(sv.Detections(
            xyxy=det.boxes[keep].reshape(-1, 4), confidence=det.scores[keep],
            class_id=np.array([names.index(det.labels[i]) for i in keep], int)))
        return Trackings(boxes=tracked.xyxy, labels=[names[c] for c in tracked.class_id],
                         scores=tracked.confidence if tracked.confidence is not None else np.zeros(len(tracked)),
                         track_ids=tracked.tracker_id, image_width=det.image_width,
                         image_height=det.image_height, stamp=det.stamp, frame_id=det.frame_id)

    # --- actions ----------------------------------------------------------------------------
    def _media_path(self, kind: str, ext: str) -> str:
        os.makedirs(self.config.media_dir, exist_ok=True)
        self._media_count += 1
        stamp = time.strftime("%Y%m%d-%H%M%S")
        return os.path.abspath(os.path.join(self.config.media_dir, f"{self.name}-{kind}-{stamp}-{self._media_count}.{ext}"))

    def take_picture(self, path: str | None = None) -> str:
        """Save the current frame (PNG or JPEG by the file name); returns its path."""
        import cv2

        if self._frame is None:
            raise RuntimeError(f"{self._label()}: no frame yet; take_picture needs a frame on "
                               f"{', '.join(t.name for t in self.inputs)}")
        path = path or self._media_path("picture", "png")
        if not cv2.imwrite(path, cv2.cvtColor(self._frame, cv2.COLOR_RGB2BGR)):
            raise OSError(f"{self._label()}: could not write {path!r} (is the folder writable?)")
        self.logger.info("%s: picture saved to %s", self._label(), path)
        return path

    def record_video(self, seconds: float, path: str | None = None) -> str:
        """Record the next ``seconds`` of annotated frames as an mp4; returns its path."""
        import cv2

        if not float(seconds) > 0:
            raise ValueError(f"{self._label()}: record_video needs seconds > 0, got {seconds!r}")
        if self._frame is None:
            raise RuntimeError(f"{self._label()}: no frame yet; record_video starts at the first frame")
        self._close_writer()
        path = path or self._media_path("video", "mp4")
        h, w = self._frame.shape[:2]
        writer = cv2.VideoWriter(path, cv2.VideoWriter.fourcc(*"mp4v"), self.config.video_fps, (w, h))
        if not writer.isOpened():
            raise OSError(f"{self._label()}: opencv cannot write mp4 to {path!r}")
        self._writer, self._record_until, self._video_size = writer, time.monotonic() + float(seconds), (w, h)
        self.logger.info("%s: recording %.1f s to %s", self._label(), float(seconds), path)
        return path

    def _record(self, rgb: np.ndarray) -> None:
        import cv2

        if self._writer is None:
            return
        if time.monotonic() > self._record_until:
            self._close_writer()
            return
        if (rgb.shape[1], rgb.shape[0]) != self._video_size:
            rgb = cv2.resize(rgb, self._video_size)
        self._writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))

    def _close_writer(self) -> None:
        if self._writer is not None:
            self._writer.release()
            self._writer = None

    def track(self, label: str) -> list[str]:
        """Track ``label`` from now on (tracking turns on); returns the labels tracked."""
        if not isinstance(label, str) or not label:
            raise ValueError(f"{self._label()}: track needs a label name, got {label!r}")
        if label not in self.config.track_labels:
            self.config.track_labels.append(label)
        self.config.enable_tracking = True
        return list(self.config.track_labels)

    def on_shutdown(self) -> None:
        self._close_writer()
