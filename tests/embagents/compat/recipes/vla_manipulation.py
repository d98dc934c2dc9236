"""VLA manipulation: a LeRobot policy drives the arm; a spoken "stop" halts it."""

import os

from agents.clients import LeRobotClient
from agents.components import VLA
from agents.config import VLAConfig
from agents.models import LeRobotPolicy
from agents.ros import Action, Event, Launcher, Topic

state = Topic(name="joint_states", msg_type="JointState")
camera = Topic(name="front_camera", msg_type="Image")
joints_action = Topic(name="joint_command", msg_type="JointState")
task = Topic(name="task", msg_type="String")

policy = LeRobotPolicy(name="smolvla", checkpoint="lerobot/smolvla_base", policy_type="smolvla",
                       actions_per_chunk=50)
client = LeRobotClient(model=policy, host="127.0.0.1", port=8080)

joints_map = {f"shoulder_{i}": f"arm_joint{i}" for i in (1, 2)}
config = VLAConfig(
    observation_sending_rate=3.0,
    action_sending_rate=30.0,
    joint_names_map=joints_map,
    camera_inputs_map={"front": "front_camera"},
    robot_urdf_file=os.path.join(os.path.dirname(os.path.abspath(__file__)), "two_joint_arm.urdf"),
)

vla = VLA(
    inputs=[state, camera, task],
    outputs=[joints_action],
    model_client=client,
    config=config,
    component_name="vla",
)

stop_said = Event(event_condition=task.msg.data == "stop", on_change=True)
pick_said = Event(event_condition=task.msg.data == "pick", on_change=True)

launcher = Launcher()
launcher.enable_ui(inputs=[task, state, camera])
launcher.add_pkg(components=[vla],
                 events_actions={stop_said: Action(method=vla.stop),
                                 pick_said: Action(method=vla.manipulate, args=("pick up the red cube",))})
launcher.bringup()
