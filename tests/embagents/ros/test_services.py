"""ROS services both ways through the bridge, against a plain rclpy peer in another process."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("rclpy", reason="ROS 2 bridge tests need: pip install 'embagents[ros]'")
pytest.importorskip("std_srvs", reason="needs the std_srvs wheel: pip install ros-std-srvs")

DOMAIN_ID = 81 + os.getpid() % 60

SYSTEM = '''
from embagents import Component, String, System, Topic
from embagents.ros import RosInput, RosLifecycle, RosOutput, RosService, ros_call

go, homed = Topic("go", String), Topic("homed", String)


class Memory(Component):
    def locate(self):
        return "the cup is on the kitchen table"

    def fail(self):
        raise RuntimeError("no map loaded")


class Homer(Component):
    allowed_inputs = {"Required": [String]}
    allowed_outputs = {"Required": [String]}

    def _execution_step(self, **inputs):
        reply = ros_call("/arm/home", "std_srvs/Trigger", timeout=5)
        results = [f"{reply.success}:{reply.message}"]
        for name, srv_type in (("/arm/missing", "std_srvs/Trigger"), ("/arm/home", "std_srvs/SetBool"),
                               ("/arm/stuck", "std_srvs/Trigger")):
            try:
                ros_call(name, srv_type, timeout=1)
            except Exception as e:
                results.append(f"{type(e).__name__}: {e}")
        self.publish(homed, String(data=" | ".join(results)))


system = System(
    [Memory(name="memory", trigger=None), Homer(name="homer", inputs=[go], outputs=[homed], trigger=go)],
    ros=[RosService("/memory/locate", "std_srvs/Trigger", component="memory", method="locate"),
         RosService("/memory/fail", "std_srvs/Trigger", component="memory", method="fail"),
         RosInput("/go", "std_msgs/String"), RosOutput("homed", ros_type="std_msgs/String"),
         RosLifecycle(["memory"])],
)
'''

PEER = r"""
import sys, time, rclpy
from std_msgs.msg import String
from std_srvs.srv import Trigger
deadline = time.time() + float(sys.argv[1])
rclpy.init()
node = rclpy.create_node("arm_peer")
def home(request, response):
    response.success, response.message = True, "homed"
    return response
node.create_service(Trigger, "/arm/home", home)
node.create_service(Trigger, "/arm/stuck", lambda request, response: time.sleep(3) or response)  # takes it, then silent
pub = node.create_publisher(String, "/go", 10)
got = []
node.create_subscription(String, "/homed", lambda m: got.append(m.data), 10)
for name in ("/memory/locate", "/memory/fail"):
    client = node.create_client(Trigger, name)
    if not client.wait_for_service(timeout_sec=max(1.0, deadline - time.time())):
        print("NO SERVICE", name, flush=True)
        continue
    future = client.call_async(Trigger.Request())
    rclpy.spin_until_future_complete(node, future, timeout_sec=10)
    r = future.result()
    print("SERVED", name, r.success if r else None, r.message if r else None, flush=True)
while not got and time.time() < deadline:
    pub.publish(String(data="go"))
    end = time.time() + 1.0
    while not got and time.time() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
print("CALLED", got[0] if got else "nothing", flush=True)

from lifecycle_msgs.msg import Transition, TransitionEvent
from lifecycle_msgs.srv import ChangeState, GetAvailableTransitions, GetState
events = []
node.create_subscription(TransitionEvent, "/memory/transition_event", events.append, 10)
def call(srv_type, name, request):
    client = node.create_client(srv_type, name)
    client.wait_for_service(timeout_sec=10)
    f = client.call_async(request)
    rclpy.spin_until_future_complete(node, f, timeout_sec=10)
    return f.result()
print("STATE", call(GetState, "/memory/get_state", GetState.Request()).current_state.label, flush=True)
avail = call(GetAvailableTransitions, "/memory/get_available_transitions", GetAvailableTransitions.Request())
print("AVAILABLE", sorted(t.transition.label for t in avail.available_transitions), flush=True)
print("DEACTIVATE", call(ChangeState, "/memory/change_state", ChangeState.Request(transition=Transition(id=4))).success)
print("DEACTIVATE AGAIN", call(ChangeState, "/memory/change_state", ChangeState.Request(transition=Transition(id=4))).success)
print("STATE", call(GetState, "/memory/get_state", GetState.Request()).current_state.label, flush=True)
end = time.time() + 5
while not events and time.time() < end:
    rclpy.spin_once(node, timeout_sec=0.1)
for e in events:
    print("EVENT", e.transition.label, e.start_state.label, e.goal_state.label, flush=True)
"""


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> str:
    tmp_path = tmp_path_factory.mktemp("services")
    env = {**os.environ, "ROS_DOMAIN_ID": str(DOMAIN_ID), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    path = tmp_path / "system.py"
    path.write_text(textwrap.dedent(SYSTEM))
    sup = subprocess.Popen([sys.executable, "-m", "embagents.cli", "supervise", str(path)],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        out = subprocess.run([sys.executable, "-c", PEER, "60"], capture_output=True, text=True, env=env, timeout=120)
        status = subprocess.run([sys.executable, "-m", "embagents.cli", "status", "--json", "--run", str(sup.pid)],
                                capture_output=True, text=True, env=env, timeout=60)
    finally:
        sup.send_signal(signal.SIGTERM)
        log, _ = sup.communicate(timeout=30)
    assert sup.returncode == 0, log
    rows = {r["name"]: r for r in json.loads(status.stdout)["rows"]} if status.returncode == 0 else {}
    lifecycle = rows.get("memory", {}).get("lifecycle")
    return out.stdout + out.stderr + f"\nSTATUS memory {lifecycle}\n--- supervisor log ---\n" + log


def test_a_component_method_is_served_as_a_trigger_service(session: str) -> None:
    assert "SERVED /memory/locate True the cup is on the kitchen table" in session, session


def test_a_failing_method_answers_success_false_with_its_error(session: str) -> None:
    assert "SERVED /memory/fail False memory.fail: " in session and "no map loaded" in session, session


def test_a_component_calls_a_ros_service(session: str) -> None:
    assert "CALLED True:homed | " in session, session


def test_a_missing_service_is_a_timeout_naming_it(session: str) -> None:
    assert "TimeoutError: ROS service /arm/missing did not answer within 1" in session, session
    assert "no server for it is up" in session, session


def test_a_type_mismatch_is_named(session: str) -> None:
    assert "ValueError: ROS service /arm/home is a std_srvs/srv/Trigger, not a std_srvs/srv/SetBool (a type mismatch)" \
        in session, session


def test_change_state_deactivates_a_component_and_status_shows_it(session: str) -> None:
    assert "STATE active" in session and "AVAILABLE ['deactivate', 'shutdown']" in session, session
    assert "DEACTIVATE True" in session and "STATE inactive" in session, session
    assert "STATUS memory inactive" in session, session
    assert "EVENT deactivate active inactive" in session, session


def test_an_invalid_transition_gets_ros_failure_result(session: str) -> None:
    assert "DEACTIVATE AGAIN False" in session, session


def test_a_server_that_takes_the_request_and_goes_silent_is_a_timeout_saying_so(session: str) -> None:
    assert "TimeoutError: ROS service /arm/stuck did not answer within 1.0 s: its server took the request and went " \
           "silent" in session, session


# Ticks from ROS go through the bridge to a relay component and back to ROS as echoes; a component
# calls the peer's slow service when /call comes, and sends its answer back on /called.
SLOW_SYSTEM = '''
from embagents import Component, String, System, Topic
from embagents.ros import RosInput, RosOutput, ros_call

ticks, echo, call, called = Topic("ticks", String), Topic("echo", String), Topic("call", String), Topic("called", String)


class Relay(Component):
    allowed_inputs = {"Required": [String]}
    allowed_outputs = {"Required": [String]}

    def _execution_step(self, **inputs):
        self.publish(echo, String(data="echo"))


class Caller(Component):
    allowed_inputs = {"Required": [String]}
    allowed_outputs = {"Required": [String]}

    def _execution_step(self, **inputs):
        reply = ros_call("/slow", "std_srvs/Trigger", timeout=10)
        self.publish(called, String(data=f"{reply.success}:{reply.message}"))


system = System(
    [Relay(name="relay", inputs=[ticks], outputs=[echo], trigger=ticks),
     Caller(name="caller", inputs=[call], outputs=[called], trigger=call)],
    ros=[RosInput("/ticks", "std_msgs/String"), RosOutput("echo", ros_type="std_msgs/String"),
         RosInput("/call", "std_msgs/String"), RosOutput("called", ros_type="std_msgs/String")],
)
'''

# A plain rclpy peer: /ticks every 20 ms (a thread); once echoes come back, /call until its /slow Trigger
# is called: that call sleeps 3 s (its own callback group: /echo is read meanwhile). Prints when the call
# ran, when each echo arrived and the answer.
SLOW_PEER = r"""
import json, sys, threading, time, rclpy
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from std_msgs.msg import String
from std_srvs.srv import Trigger
deadline = time.time() + float(sys.argv[1])
rclpy.init()
node = rclpy.create_node("slow_peer")
window, echoes, answers = [], [], []
def slow(request, response):
    if not window:
        window.append(time.monotonic())
        time.sleep(3)
        window.append(time.monotonic())
    response.success, response.message = True, "slow done"
    return response
node.create_service(Trigger, "/slow", slow, callback_group=MutuallyExclusiveCallbackGroup())
node.create_subscription(String, "/echo", lambda m: echoes.append(time.monotonic()), 100,
                         callback_group=MutuallyExclusiveCallbackGroup())
node.create_subscription(String, "/called", lambda m: answers.append(m.data), 10,
                         callback_group=MutuallyExclusiveCallbackGroup())
ticks, calls = node.create_publisher(String, "/ticks", 100), node.create_publisher(String, "/call", 10)
stop = threading.Event()
def tick():
    n = 0
    while not stop.wait(0.02):
        ticks.publish(String(data="tick"))
        n += 1
        if echoes and not window and n % 25 == 0:
            calls.publish(String(data="call"))
threading.Thread(target=tick, daemon=True).start()
executor = MultiThreadedExecutor(num_threads=3)
executor.add_node(node)
while not answers and time.time() < deadline:
    executor.spin_once(timeout_sec=0.1)
stop.set()
print(json.dumps({"window": window, "echoes": echoes, "answers": answers}), flush=True)
"""


def test_topics_flow_both_ways_while_a_called_service_is_slow(tmp_path: Path) -> None:
    env = {**os.environ, "ROS_DOMAIN_ID": str(DOMAIN_ID + 1), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    path = tmp_path / "system.py"
    path.write_text(textwrap.dedent(SLOW_SYSTEM))
    sup = subprocess.Popen([sys.executable, "-m", "embagents.cli", "supervise", str(path)],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        out = subprocess.run([sys.executable, "-c", SLOW_PEER, "60"], capture_output=True, text=True, env=env,
                             timeout=120)
    finally:
        sup.send_signal(signal.SIGTERM)
        log, _ = sup.communicate(timeout=30)
    got = json.loads(out.stdout or "{}") if out.returncode == 0 else {}
    assert got.get("answers") == ["True:slow done"], out.stdout + out.stderr + log
    start, end = got["window"]
    during = [t for t in got["echoes"] if start < t < end]
    # ~150 ticks went out during the 3 s call; each came through the bridge, the relay and the bridge again.
    assert len(during) >= 10, f"{len(during)} echoes during the slow call ({len(got['echoes'])} in all)\n{log}"



# Serves /t/quick, /t/slow and /t/hang of actor "t" (timeout 2 s) through a bridge, and calls them from rclpy
# in this process (after the fork server is forked: it must not inherit Fast DDS threads). argv[1]: "kill"
# SIGKILLs "t" while /t/hang waits for it, "stop" stops the bridge then.
SERVED = r"""
import json, signal, sys, threading, time
import embagents.requests  # registers Call, which the bridge sends the target
from actors import Actor, ActorSystem
from embagents.ros.bridge_actor import RosBridgeActor


class Target(Actor):
    def on_receive(self, message):
        time.sleep({"quick": 0.0, "slow": 1.0, "hang": 60.0}[message.method])
        return f"{message.method} done"


services = [{"ros_name": f"/t/{m}", "srv_type": "std_srvs/Trigger", "component": "t", "method": m, "timeout": 2.0}
            for m in ("quick", "slow", "hang")]
with ActorSystem() as asys:
    asys.spawn(Target, "t")
    asys.spawn(RosBridgeActor, "bridge", None, "served_calls_bridge", [], [], services, wait=60)
    import rclpy
    from std_srvs.srv import Trigger
    rclpy.init()
    node = rclpy.create_node("served_calls_client")
    clients = {}

    def call(*names):  # all at once; their answers, in order
        for name in names:
            if name not in clients:
                clients[name] = node.create_client(Trigger, name)
                clients[name].wait_for_service(timeout_sec=30)
        futures = [clients[name].call_async(Trigger.Request()) for name in names]
        end = time.time() + 30
        while not all(f.done() for f in futures) and time.time() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
        return json.dumps([[f.result().success, f.result().message] if f.done() else None for f in futures])

    print("AT ONCE", call("/t/slow", "/t/quick", "/t/quick"), flush=True)
    if sys.argv[1] == "kill":
        threading.Timer(0.5, asys.signal, ["t", signal.SIGKILL]).start()
        print("KILLED MID CALL", call("/t/hang"), flush=True)
        print("NOBODY THERE", call("/t/quick"), flush=True)
    else:
        threading.Timer(0.5, asys.stop, ["bridge"]).start()
        print("STOPPED MID CALL", call("/t/hang"), flush=True)
    node.destroy_node()
    rclpy.shutdown()
"""


def _served(scenario: str, domain: int) -> dict[str, Any]:
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    out = subprocess.run([sys.executable, "-c", SERVED, scenario], capture_output=True, text=True, env=env, timeout=180)
    lines = [line.split(" [", 1) for line in out.stdout.splitlines() if " [" in line]
    return {what: json.loads("[" + answer) for what, answer in lines} | {"log": out.stdout + out.stderr}


def test_calls_at_once_are_each_answered_and_a_component_killed_mid_call_is_an_error_not_a_hang() -> None:
    got = _served("kill", DOMAIN_ID + 2)
    assert got.get("AT ONCE") == [[True, "slow done"], [True, "quick done"], [True, "quick done"]], got["log"]
    [(ok, text)] = got["KILLED MID CALL"]
    assert not ok and "t.hang: " in text and "died" in text, got["log"]
    assert got["NOBODY THERE"] == [[False, "t.quick: no answer within 2.0 s"]], got["log"]  # the declared timeout


def test_a_bridge_stopped_while_a_call_waits_for_its_component_answers_the_call() -> None:
    got = _served("stop", DOMAIN_ID + 3)
    assert got.get("AT ONCE") == [[True, "slow done"], [True, "quick done"], [True, "quick done"]], got["log"]
    assert got["STOPPED MID CALL"] == [[False, "t.hang: the ROS bridge is stopping"]], got["log"]  # not its 2 s timeout
