"""A ROS action through the bridge (test_msgs/Fibonacci, the action type with a wheel), against a plain rclpy server."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap

import pytest

pytest.importorskip("rclpy", reason="ROS 2 bridge tests need: pip install 'embagents[ros]'")
pytest.importorskip("test_msgs", reason="needs the test_msgs wheel: pip install ros-test-msgs")

DOMAIN_ID = 141 + os.getpid() % 60

SYSTEM = '''
from embagents import Component, String, System, Topic
from embagents.msgs import RosMessage
from embagents.ros import RosAction, RosInput, RosOutput

go, out = Topic("fib_go", String), Topic("fib_out", String)
goal, feedback, result, cancel = (Topic("fib_goal", RosMessage), Topic("fib_feedback", RosMessage),
                                  Topic("fib_result", RosMessage), Topic("fib_cancel", String))


class Fib(Component):
    allowed_inputs = {"Required": [String], "Optional": [RosMessage]}
    allowed_outputs = {"Required": [String], "Optional": [RosMessage]}

    def _execution_step(self, **inputs):
        fresh = self.fresh_inputs
        if "fib_go" in fresh:
            text = inputs["fib_go"].data
            if text == "cancel":
                self.publish(cancel, String(data="stop"))
            else:
                self.publish(goal, RosMessage("", {"order": int(text)}))
        if "fib_feedback" in fresh:
            self.publish(out, String(data=f"feedback {inputs['fib_feedback'].sequence.tolist()}"))
        if "fib_result" in fresh:
            r = inputs["fib_result"]
            seq = r.result.sequence.tolist() if r.result is not None else None
            self.publish(out, String(data=f"result {r.status} {seq}"))


system = System(
    [Fib(name="fib", inputs=[go, feedback, result], outputs=[out, goal, cancel], trigger=[go, feedback, result])],
    ros=[RosAction("/fibonacci", "test_msgs/Fibonacci", goal="fib_goal", feedback="fib_feedback",
                   result="fib_result", cancel="fib_cancel"),
         RosInput("/fib_go", "std_msgs/String"), RosOutput("fib_out", ros_type="std_msgs/String")],
)
'''

PEER = r"""
import sys, time, threading, rclpy
from rclpy.action import ActionServer, CancelResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from std_msgs.msg import String
from test_msgs.action import Fibonacci
deadline = time.time() + float(sys.argv[1])
rclpy.init()
node = rclpy.create_node("fib_server")
def execute(handle):
    seq = [0, 1]
    for i in range(1, handle.request.order):
        if handle.is_cancel_requested:
            handle.canceled()
            return Fibonacci.Result(sequence=seq)
        seq.append(seq[i] + seq[i - 1])
        handle.publish_feedback(Fibonacci.Feedback(sequence=seq))
        time.sleep(0.05 if handle.request.order < 20 else 0.2)
    handle.succeed()
    return Fibonacci.Result(sequence=seq)
ActionServer(node, Fibonacci, "/fibonacci", execute, callback_group=ReentrantCallbackGroup(),
             cancel_callback=lambda _h: CancelResponse.ACCEPT)
pub = node.create_publisher(String, "/fib_go", 10)
got = []
node.create_subscription(String, "/fib_out", lambda m: got.append(m.data), 100)
ex = MultiThreadedExecutor(4)
ex.add_node(node)
threading.Thread(target=ex.spin, daemon=True).start()
def wait_for(prefix, t):
    end = time.time() + t
    while time.time() < end and not any(g.startswith(prefix) for g in got):
        time.sleep(0.05)
while not got and time.time() < deadline:
    pub.publish(String(data="5"))
    wait_for("", 1.0)
wait_for("result", 10)
got_first = list(got)
got.clear()
pub.publish(String(data="30"))
wait_for("feedback", 10)
pub.publish(String(data="cancel"))
wait_for("result", 10)
for line in got_first + ["--- second goal ---"] + got:
    print("OUT", line, flush=True)
"""


def test_a_goal_gets_feedback_and_its_result_and_a_second_is_canceled(tmp_path) -> None:
    env = {**os.environ, "ROS_DOMAIN_ID": str(DOMAIN_ID), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    path = tmp_path / "system.py"
    path.write_text(textwrap.dedent(SYSTEM))
    sup = subprocess.Popen([sys.executable, "-m", "embagents.cli", "supervise", str(path)],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        out = subprocess.run([sys.executable, "-c", PEER, "60"], capture_output=True, text=True, env=env, timeout=120)
    finally:
        sup.send_signal(signal.SIGTERM)
        log, _ = sup.communicate(timeout=30)
    text = out.stdout + out.stderr + "\n--- supervisor log ---\n" + log
    assert sup.returncode == 0, text
    assert "OUT feedback [0, 1, 1]" in text, text
    assert "OUT result succeeded [0, 1, 1, 2, 3, 5]" in text, text
    second = text.split("--- second goal ---", 1)[1]
    assert "OUT result canceled [" in second, text
