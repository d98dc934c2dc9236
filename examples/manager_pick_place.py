"""ROS Base style (a): a handler owns a fine-grained pick-and-place state machine.

    pip install -e .                # add [vision] (OpenCV) for the filmstrip
    embagents supervise examples/manager_pick_place.py

Offline, no ROS, about ten seconds. What runs, each in its own process:

- ``table`` (a component at 20 Hz): a simulated table seen from above with
  three coloured cubes, a bin on the right and a gripper; it publishes camera
  frames (``camera/image_raw``, Image) and the arm's state (``arm/state``), and
  moves the gripper as ``arm/cmd`` says;
- ``pick_place`` (the manager, 20 Hz): its node caches the latest frame and
  arm state; the handshake waits for a first frame and a first arm state; the
  ``PickPlace`` handler sends frames to the detector and drives the arm:
  look -> approach -> grasp -> carry -> release -> look ... -> done;
- ``pick_place.detector`` (the heavy detector, an *isolated* agent): finds the
  cubes in a frame (numpy colour masks; a real detector model slots in the
  same way). ``isolated=False`` would run it as a thread of the manager's process.

Every detection is published on ``detections`` (Detections). When the table
is clear the manager publishes on ``system_stop`` and the run ends; with
opencv installed it first writes a filmstrip of the first cube's states to
``$EMBAGENTS_PICK_PLACE_OUT/filmstrip.png`` (default ``./pick_place_out``). SIGKILL the
manager mid-mission (``kill -9`` the pid ``embagents status`` shows) and it
resumes in the state it was in ("restarted: resuming at tick ...: handler
'PickPlace' in state 'carry'").
"""

from __future__ import annotations

import json
import os
import time
from typing import Any

import numpy as np

from embagents.components import Component
from embagents.manager import Agent, HandshakeRule, Manager, Node, State, StateMachineHandler
from embagents.msgs import Detections, Image, String
from embagents.system import SYSTEM_STOP, System
from embagents.topic import Topic

W, H, CUBE, BIN_X = 320, 240, 16, 264
COLOURS = {"red": (220, 40, 40), "green": (40, 190, 60), "blue": (50, 80, 230)}

image = Topic("camera/image_raw", Image, queue_size=1)
arm_cmd = Topic("arm/cmd", String, queue_size=10, keep="all")
arm_state = Topic("arm/state", String, queue_size=1)
detections = Topic("detections", Detections)
stop = Topic(SYSTEM_STOP, String)


class Table(Component):
    """The simulated world: cubes, a bin, a gripper that moves 8 px per step toward its target."""

    allowed_inputs = {"Optional": [String]}
    allowed_outputs = {"Required": [Image, String]}

    def on_activate(self) -> None:
        self.cubes = {"red": [60.0, 70.0], "green": [120.0, 170.0], "blue": [190.0, 90.0]}
        self.gripper, self.target = [160.0, 120.0], [160.0, 120.0]
        self.holding: str | None = None

    def _execution_step(self, **inputs: Any) -> None:
        cmd = inputs.get("arm/cmd")
        if cmd is not None and "arm/cmd" in self.fresh_inputs:
            self._obey(json.loads(cmd.data))
        step = np.subtract(self.target, self.gripper)
        dist = float(np.hypot(*step))
        if dist > 0:
            self.gripper = list(np.add(self.gripper, step * min(1.0, 8.0 / dist)))
        if self.holding:
            self.cubes[self.holding] = list(self.gripper)
        moving = float(np.hypot(*np.subtract(self.target, self.gripper))) > 0.5
        self.publish(image, Image(data=self._render(), stamp=time.time(), frame_id="table_camera"))
        self.publish(arm_state, String(data=json.dumps({"at": self.gripper, "moving": moving,
                                                        "holding": self.holding})))

    def _obey(self, cmd: dict[str, Any]) -> None:
        if "move" in cmd:
            self.target = [float(v) for v in cmd["move"]]
        elif cmd.get("grip"):
            near = [c for c, p in self.cubes.items() if np.hypot(*np.subtract(p, self.gripper)) < 6]
            self.holding = near[0] if near else None
        else:
            self.holding = None

    def _render(self) -> np.ndarray:
        frame = np.full((H, W, 3), 200, np.uint8)
        frame[:, BIN_X:] = 90  # the bin
        for colour, (x, y) in self.cubes.items():
            x0, y0 = int(x) - CUBE // 2, int(y) - CUBE // 2
            frame[max(0, y0):y0 + CUBE, max(0, x0):x0 + CUBE] = COLOURS[colour]
        gx, gy = int(self.gripper[0]), int(self.gripper[1])
        frame[max(0, gy - 1):gy + 2, max(0, gx - 10):gx + 11] = 255  # the gripper: a white cross
        frame[max(0, gy - 10):gy + 11, max(0, gx - 1):gx + 2] = 255
        return frame


class CubeDetector:
    """The heavy part: finds each cube's box in a frame by its colour."""

    def detect(self, frame: np.ndarray) -> list[dict[str, Any]]:
        found = []
        for colour, rgb in COLOURS.items():
            mask = np.all(np.abs(frame.astype(np.int16) - rgb) < 30, axis=2)
            ys, xs = np.nonzero(mask)
            if len(xs) > CUBE * CUBE // 4:
                found.append({"label": colour, "box": [int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max())],
                              "score": min(1.0, len(xs) / (CUBE * CUBE))})
        return found


camera = Node("camera", subscribe=[image, arm_state], publish=[arm_cmd, detections, stop])
detector = Agent("detector", CubeDetector, isolated=True)  # isolated=False: a thread of the manager's process


class PickPlace(StateMachineHandler):
    """look -> approach -> grasp -> carry -> release -> look ... -> done (the table is clear)."""

    transitions = {
        "look": {"cube_seen": "approach", "table_clear": "done"},
        "approach": {"above_cube": "grasp"},
        "grasp": {"gripped": "carry", "missed": "look"},
        "carry": {"above_bin": "release"},
        "release": {"dropped": "look"},
    }

    def __init__(self) -> None:
        super().__init__()
        self.pending: Any = None  # the detector's future
        self.strip: list[tuple[str, np.ndarray]] = []  # the frame on entering each state, for the filmstrip

    def on_tick(self, state: State, tick: int) -> None:
        super().on_tick(state, tick)
        if len(self.strip) < 6 and (not self.strip or self.strip[-1][0] != self.current):
            self.strip.append((self.current, camera.latest(image).data.copy()))

    def arm(self) -> dict[str, Any]:
        return json.loads(camera.latest(arm_state).data)

    def command(self, **cmd: Any) -> None:
        camera.publish(arm_cmd, String(data=json.dumps(cmd)))

    def tick_look(self, state: State) -> str | None:
        if self.pending is None:
            self.pending = detector.call("detect", camera.latest(image).data)
            return None
        if not self.pending.done():
            return None  # the loop keeps its rate while the detector works in its own process
        found, self.pending = self.pending.result(), None
        camera.publish(detections, Detections(
            boxes=np.array([d["box"] for d in found], np.float32).reshape(-1, 4), labels=[d["label"] for d in found],
            scores=np.array([d["score"] for d in found], np.float32), image_width=W, image_height=H))
        on_table = [d for d in found if d["box"][2] < BIN_X]
        if not on_table:
            return "table_clear"
        x0, y0, x1, y1 = on_table[0]["box"]
        state["target"] = on_table[0]["label"]
        state["target_at"] = [(x0 + x1) / 2, (y0 + y1) / 2]
        self.command(move=state["target_at"])
        return "cube_seen"

    def tick_approach(self, state: State) -> str | None:
        arm = self.arm()
        if arm["moving"] or np.hypot(*np.subtract(arm["at"], state["target_at"])) > 1:
            return None
        self.command(grip=True)
        return "above_cube"

    def on_enter_grasp(self, state: State) -> None:
        state["grasp_ticks"] = 0

    def tick_grasp(self, state: State) -> str | None:
        if self.arm()["holding"] == state["target"]:
            state["bin_at"] = [BIN_X + 28, 40 + 40 * int(state.get("placed", 0))]
            self.command(move=state["bin_at"])
            return "gripped"
        state["grasp_ticks"] += 1
        return "missed" if state["grasp_ticks"] > 20 else None  # a second without the cube: look again

    def tick_carry(self, state: State) -> str | None:
        if np.hypot(*np.subtract(self.arm()["at"], state["bin_at"])) > 1:
            return None
        self.command(grip=False)
        return "above_bin"

    def tick_release(self, state: State) -> str | None:
        if self.arm()["holding"] is not None:
            return None
        state["placed"] = int(state.get("placed", 0)) + 1
        print(f"placed the {state['target']} cube ({state['placed']} in the bin)", flush=True)
        return "dropped"

    def on_enter_done(self, state: State) -> None:
        self.write_strip()
        print(f"done: the table is clear ({state.get('placed', 0)} cubes in the bin)", flush=True)
        camera.publish(stop, String(data="pick_place done"))

    def write_strip(self) -> None:
        try:
            import cv2
        except ImportError:
            return  # the filmstrip is a picture for people; the mission does not need it
        tiles = []
        for name, frame in self.strip:
            tile = cv2.cvtColor(frame, cv2.COLOR_RGB2BGR)
            cv2.putText(tile, name, (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 2)
            tiles.append(np.pad(tile, ((2, 2), (2, 2), (0, 0))))
        while len(tiles) < 6:  # a restart forgets the frames it had kept
            tiles.append(np.zeros((H + 4, W + 4, 3), np.uint8))
        out = os.path.abspath(os.environ.get("EMBAGENTS_PICK_PLACE_OUT", "pick_place_out"))
        os.makedirs(out, exist_ok=True)
        cv2.imwrite(os.path.join(out, "filmstrip.png"), np.vstack([np.hstack(tiles[:3]), np.hstack(tiles[3:6])]))
        print(f"filmstrip: {os.path.join(out, 'filmstrip.png')}", flush=True)


manager = Manager(
    20, name="pick_place", nodes=[camera], agents=[detector], handlers=[PickPlace()],
    handshake=[HandshakeRule.first_message(image), HandshakeRule.first_message(arm_state)],
    handshake_timeout=10.0, on_handler_error="crash", hang_timeout=5.0,
)

system = System([Table(name="table", inputs=[arm_cmd], outputs=[image, arm_state], trigger=20.0)],
                managers=[manager], name="pick_place")
