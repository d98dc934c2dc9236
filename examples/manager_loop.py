"""A manager main loop: wait for a camera, drive to a target, stop.

Run it with ``python examples/manager_loop.py`` (``pip install -e .``: no extra); it finishes on its own in
about four seconds, with no ROS and no network. What happens:

- a simulated camera (an attached node with its own thread) starts sending
  frames after 0.3 s; the handshake holds tick 1 back until the first one;
- a pykka agent (attached, a thread in this process) simulates the robot
  base: it takes speed commands and reports the distance left to the target;
- the ``Mission`` state machine goes idle -> approach once the target is in
  view, then approach -> done below 5 cm, and stops the manager;
- the achieved loop rate is logged every second; Ctrl-C stops cleanly.
"""

from __future__ import annotations

import logging
import math
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pykka

try:
    import embagents  # noqa: F401
except ModuleNotFoundError:  # running from a checkout without `pip install -e .`
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from embagents.manager import (
    AttachedNode,
    HandshakeRule,
    Manager,
    State,
    StateMachineHandler,
)


class Camera(AttachedNode):
    """Sends ``{"seq", "target_visible"}`` frames at ``fps`` after a warm-up."""

    def __init__(self, on_frame: Callable[[Any], None], fps: float = 15.0, warmup: float = 0.3):
        super().__init__("camera")
        self.on_frame = on_frame
        self.fps = fps
        self.warmup = warmup
        self.frames = 0
        self._stopped = threading.Event()
        self._thread = threading.Thread(target=self._run, name="camera", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stopped.set()
        self._thread.join()

    def _run(self) -> None:
        if self._stopped.wait(self.warmup):
            return
        while not self._stopped.is_set():
            # The target comes into view from the 10th frame on.
            self.on_frame({"seq": self.frames, "target_visible": self.frames >= 10})
            self.frames += 1
            self._stopped.wait(1.0 / self.fps)


class Base(pykka.ThreadingActor):
    """The robot base: integrates the commanded speed into the distance left."""

    def __init__(self, report: Callable[[float], None], distance: float = 1.0) -> None:
        super().__init__()
        self.report = report
        self.distance = distance
        self.speed = 0.0
        self.last = time.monotonic()

    def on_start(self) -> None:
        self.report(self.distance)

    def drive(self, speed: float) -> None:
        now = time.monotonic()
        self.distance = max(0.0, self.distance - self.speed * (now - self.last))
        self.speed, self.last = speed, now
        self.report(self.distance)


class Mission(StateMachineHandler):
    """idle -> approach -> done, driven by the camera and the distance reading."""

    transitions = {
        "idle": {"target_seen": "approach"},
        "approach": {"arrived": "done"},
    }

    def __init__(self, base: Any, on_done: Callable[[], None]) -> None:
        super().__init__()
        self.base = base  # a pykka proxy: calls are messages to the agent
        self.on_done = on_done

    def tick_idle(self, state: State) -> str | None:
        return "target_seen" if state.camera["target_visible"] else None

    def tick_approach(self, state: State) -> str | None:
        distance = state.get("distance", math.inf)
        if distance < 0.05:
            return "arrived"
        self.base.drive(min(0.5, distance + 0.1))  # slow down near the target
        return None

    def on_enter_done(self, state: State) -> None:
        self.base.drive(0.0)
        self.on_done()

    def on_stop(self, state: State) -> None:
        self.base.drive(0.0)  # runs before attached agents stop: halt the motors


def progress(state: State, tick: int) -> None:
    """A plain function handler: a line every 20 ticks."""
    if tick % 20 == 0:
        print(f"tick {tick:3d}: distance {state.get('distance', math.nan):.3f} m")


def main() -> int:
    logging.basicConfig(
        level=logging.INFO, format="%(relativeCreated)6.0f ms  %(name)-27s %(message)s"
    )
    manager = Manager(
        rate_hz=20,
        handshake=[
            HandshakeRule.message_received(
                "camera", name="first_camera_frame", description="a frame from the camera"
            ),
            HandshakeRule.message_received(
                "distance", name="odometry", description="a distance from the base"
            ),
        ],
        handshake_timeout=5.0,
        log_rate_every=1.0,
        name="example",
    )
    signal.signal(signal.SIGINT, lambda *_: manager.stop())
    with manager:
        base = manager.attach_actor(Base, manager.on_message("distance")).proxy()
        camera = manager.attach(Camera(manager.on_message("camera")))
        mission = manager.add_handler(Mission(base, on_done=manager.stop))
        manager.add_handler(progress)
        attached = manager.attached
        started = time.monotonic()
        ticks = manager.run(max_ticks=400)  # a safety net: 20 s at 20 Hz
        elapsed = time.monotonic() - started

    print(f"ticks:          {ticks} in {elapsed:.2f} s (target 20 Hz, {manager.overruns} overruns)")
    print(f"states visited: {' -> '.join(mission.history)}")
    print(f"camera frames:  {camera.frames}")
    print(f"distance left:  {manager.state.distance:.3f} m")
    print(f"attached:       {', '.join(attached)} (released in reverse order)")
    return 0 if mission.current == "done" else 1


if __name__ == "__main__":
    sys.exit(main())
