"""The robot of the two-host example: a camera and the Zenoh bridge; detections come back from the GPU box.

    pip install -e ".[vision,zenoh]"
    embagents supervise examples/two_hosts/gpu_box.py     # in one terminal
    embagents supervise examples/two_hosts/robot.py       # in another

The ``camera`` publishes a real photo (scikit-image's astronaut.png) at 5 Hz on
``camera/image``; the bridge exports it as ``robot1/camera/image`` (keep-latest:
a late frame is worth nothing; as JPEG: 30 KB instead of 786 KB on the link, an
``Image`` again on the other side). The GPU box's Vision finds her face and
exports ``gpu/faces``; this bridge imports it back as ``faces`` (keep-all), and
``report`` prints each detection with its round trip, then stops the system
after ``EMBAGENTS_TWO_HOSTS_N`` detections (default 20; 0: run on).
``embagents status`` shows the link (endpoint, state, msgs/s, bytes/s).
"""

from __future__ import annotations

import os
import sys
import time
from typing import Any

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from link import CONNECT, tls  # noqa: E402

from embagents.components import Component  # noqa: E402
from embagents.msgs import Detections, Image, String  # noqa: E402
from embagents.system import (
    SYSTEM_STOP,  # noqa: E402
    System,  # noqa: E402
)
from embagents.topic import Topic  # noqa: E402
from embagents.zenoh import Export, Import, ZenohBridge  # noqa: E402

N = int(os.environ.get("EMBAGENTS_TWO_HOSTS_N", "20"))


class PhotoCamera(Component):
    """A camera that sees a photo: astronaut.png, stamped with the time it is taken."""

    allowed_outputs = {"Required": [Image]}

    def on_configure(self) -> None:
        from skimage import data

        self.photo = data.astronaut()

    def _execution_step(self, **inputs: Any) -> None:
        self.publish(frames, Image(data=self.photo, stamp=time.time(), frame_id="camera"))


class Report(Component):
    """Prints each detection that came back, and the time since its frame was taken."""

    allowed_inputs = {"Required": [Detections]}
    allowed_outputs = {"Required": [String]}

    def on_activate(self) -> None:
        self.seen = 0

    def _execution_step(self, **inputs: Any) -> None:
        msg = inputs["faces"]
        self.seen += 1
        found = ", ".join(f"{label} {score:.2f}" for label, score in zip(msg.labels, msg.scores, strict=True))
        print(f"from the GPU box: {found or 'nothing'} ({1000 * (time.time() - msg.stamp):.0f} ms after the frame)",
              flush=True)
        if N and self.seen >= N:
            self.publish(stop, String(data="done"))


frames = Topic("camera/image", Image)
faces = Topic("faces", Detections, queue_size=100, keep="all")
stop = Topic(SYSTEM_STOP, String)

system = System(
    [
        PhotoCamera(name="camera", outputs=[frames], trigger=5.0),
        Report(name="report", inputs=[faces], outputs=[stop], trigger=faces),
    ],
    zenoh=ZenohBridge("robot1", exports=[Export(frames, keep="latest", compress="jpeg")],
                      imports=[Import("gpu/faces", Detections)], connect=[CONNECT], tls=tls("robot1")),
    name="robot1",
)
