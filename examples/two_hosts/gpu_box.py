"""The GPU box of the two-host example: the Zenoh bridge and Vision with a face detector.

    embagents supervise examples/two_hosts/gpu_box.py

Imports the robot's ``robot1/camera/image`` as ``camera/image`` (keep-latest),
runs Vision with the ``faces`` model actor (MTCNN's ONNX files, fetched once
from PyPI) and exports its Detections as ``gpu/faces``. It listens; the robot
connects. See robot.py for the other half, link.py for addresses and TLS.
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from link import LISTEN, tls  # noqa: E402

from embagents.components import Vision, VisionConfig  # noqa: E402
from embagents.models import DetectorModel, LocalModelClient  # noqa: E402
from embagents.msgs import Detections, Image  # noqa: E402
from embagents.system import System  # noqa: E402
from embagents.topic import Topic  # noqa: E402
from embagents.zenoh import Export, Import, ZenohBridge  # noqa: E402

frames = Topic("camera/image", Image)
faces = Topic("faces", Detections, queue_size=100, keep="all")
detector = DetectorModel(name="faces", family="mtcnn", threshold=0.9)

system = System(
    [Vision(name="vision", inputs=[frames], outputs=[faces], model_client=LocalModelClient(detector),
            config=VisionConfig())],
    models=[detector],
    zenoh=ZenohBridge("gpu", exports=[Export(faces)], imports=[Import("robot1/camera/image", Image, keep="latest")],
                      listen=[LISTEN], tls=tls("gpu")),
    name="gpu_box",
)
