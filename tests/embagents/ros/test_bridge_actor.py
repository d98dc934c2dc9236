"""The ROS 2 bridge actor in a supervised system, against real rclpy peers in other processes."""

from __future__ import annotations

import glob
import os
import re
import signal
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import pytest

pytest.importorskip("rclpy", reason="ROS 2 bridge tests need: pip install 'embagents[ros]'")

from embagents.bench.cases_ros_recovery import ECHO_SYSTEM, bridge_pid  # noqa: E402
from embagents.ros.bridge_actor import REDISCOVER_TRIES  # noqa: E402
from embagents.ros.fastdds_shm import clean_zombie_fastdds_segments, mapped_fastdds_files  # noqa: E402

DOMAIN_ID = 101 + os.getpid() % 100

LLM_SYSTEM = '''
from embagents import LLM, LLMConfig, LlamaModel, LocalModelClient, String, System, Topic
from embagents.ros import RosInput, RosOutput

text_in, text_out = Topic("text_in", String), Topic("text_out", String)
model = LlamaModel(name="tiny", local_model_path=MODEL, warmup=False)
system = System(
    [LLM(name="llm", inputs=[text_in], outputs=[text_out], model_client=LocalModelClient(model),
         config=LLMConfig(temperature=0.0, max_new_tokens=6))],
    models=[model],
    ros=[RosInput("/text_in", "std_msgs/String"), RosOutput("text_out", ros_type="std_msgs/String")],
)
'''

IMAGE_SYSTEM = '''
from embagents import System
from embagents.ros import RosInput, RosOutput

system = System(
    [],
    ros=[RosInput("/image_in", "sensor_msgs/Image", topic="image"),
         RosOutput("image", ros_topic="/image_out", ros_type="sensor_msgs/Image")],
)
'''

# A plain rclpy node: publishes on IN until something arrives on OUT, then prints it.
PEER = r"""
import sys, time, numpy as np, rclpy
from std_msgs.msg import String
from sensor_msgs.msg import Image
kind, deadline = sys.argv[1], time.time() + float(sys.argv[2])
rclpy.init()
node = rclpy.create_node("peer")
got = []
if kind == "text":
    pub = node.create_publisher(String, "/text_in", 10)
    node.create_subscription(String, "/text_out", lambda m: got.append(repr(m.data)), 10)
    make = lambda i: String(data=f"hello {i}")
else:
    pub = node.create_publisher(Image, "/image_in", 10)
    h, w = 48, 64
    pixels = (np.arange(h * w * 3) % 251).astype(np.uint8)
    def on_image(m):
        ok = m.height == h and m.width == w and m.encoding == "rgb8" and bytes(m.data) == pixels.tobytes()
        got.append("PIXELS_OK" if ok else f"PIXELS_BAD {m.height}x{m.width} {m.encoding}")
    node.create_subscription(Image, "/image_out", on_image, 10)
    def make(i):
        m = Image(height=h, width=w, encoding="rgb8", step=w * 3)
        m.data = pixels.tobytes()
        return m
i = 0
while not got and time.time() < deadline:
    pub.publish(make(i)); i += 1
    end = time.time() + 0.5
    while not got and time.time() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
print("GOT", got[0] if got else "nothing", flush=True)
"""


@pytest.fixture
def ros_env(monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
    monkeypatch.setenv("ROS_DOMAIN_ID", str(DOMAIN_ID))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    return dict(os.environ)


def _run(system_text: str, tmp_path: Path, env: dict[str, str], peer: str, timeout: float = 60) -> str:
    path = tmp_path / "system.py"
    path.write_text(textwrap.dedent(system_text))
    sup = subprocess.Popen(
        [sys.executable, "-m", "embagents.cli", "supervise", str(path)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
    )
    try:
        out = subprocess.run(
            [sys.executable, "-c", PEER, peer, str(timeout)], capture_output=True, text=True, env=env, timeout=timeout + 30
        )
    finally:
        sup.send_signal(signal.SIGTERM)
        log, _ = sup.communicate(timeout=30)
    assert sup.returncode == 0, log
    return out.stdout + out.stderr


def test_an_external_ros_node_talks_to_the_llm(tmp_path: Path, tiny_gguf: str, ros_env: dict[str, str]) -> None:
    out = _run(LLM_SYSTEM.replace("MODEL", repr(tiny_gguf)), tmp_path, ros_env, "text")
    assert "GOT '" in out, out  # an answer arrived on /text_out


def test_an_image_round_trip_keeps_every_pixel(tmp_path: Path, ros_env: dict[str, str]) -> None:
    out = _run(IMAGE_SYSTEM, tmp_path, ros_env, "image")
    assert "GOT PIXELS_OK" in out, out


def test_check_names_the_ros_extra_when_rclpy_is_missing(tmp_path: Path) -> None:
    fake = tmp_path / "no_ros"
    (fake / "rclpy").mkdir(parents=True)
    (fake / "rclpy" / "__init__.py").write_text("raise ImportError('No module named rclpy')\n")
    path = tmp_path / "system.py"
    path.write_text(textwrap.dedent(IMAGE_SYSTEM))
    env = {**os.environ, "PYTHONPATH": f"{fake}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    proc = subprocess.run(
        [sys.executable, "-m", "embagents.cli", "check", str(path)], capture_output=True, text=True, env=env, timeout=60
    )
    assert proc.returncode == 1
    assert "pip install 'embagents[ros]'" in proc.stdout + proc.stderr


def test_a_system_without_ros_runs_without_importing_rclpy(tmp_path: Path) -> None:
    code = (
        "import sys\n"
        "from embagents.check import check_system\nfrom embagents.system import load_system\n"
        "import embagents.cli.supervise, embagents.runtime\n"
        f"check_system(load_system({str(Path(__file__).parents[3] / 'examples' / 'chat.py')!r}))\n"
        "assert 'rclpy' not in sys.modules, 'rclpy was imported'\nprint('OK')\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.stdout.strip().endswith("OK"), proc.stderr


STREAMER = r"""
import json, sys, time, rclpy
from std_msgs.msg import String
rclpy.init()
node = rclpy.create_node("streamer")
pub = node.create_publisher(String, "/ping", 10)
arrivals = []
node.create_subscription(String, "/pong", lambda m: arrivals.append(time.monotonic()), 10)
end, i, flowing = time.time() + float(sys.argv[1]), 0, False
while time.time() < end:
    pub.publish(String(data=str(i))); i += 1
    t = time.time() + 0.05
    while time.time() < t:
        rclpy.spin_once(node, timeout_sec=0.01)
    if arrivals and not flowing:
        flowing = True
        print("FLOWING", flush=True)
print(json.dumps(arrivals), flush=True)
"""


def test_killing_the_bridge_mid_stream_recovers(tmp_path: Path, ros_env: dict[str, str]) -> None:
    import json
    import time

    path = tmp_path / "system.py"
    path.write_text(textwrap.dedent(ECHO_SYSTEM))
    xdg = tmp_path / "xdg"
    xdg.mkdir(mode=0o700)
    env = {**ros_env, "XDG_RUNTIME_DIR": str(xdg)}  # every file of the run goes under it
    sup = subprocess.Popen([sys.executable, "-m", "embagents.cli", "supervise", str(path)],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    peer = subprocess.Popen([sys.executable, "-c", STREAMER, "20"], stdout=subprocess.PIPE, text=True, env=ros_env)
    try:
        assert peer.stdout is not None
        assert peer.stdout.readline().strip() == "FLOWING"
        pid = bridge_pid(sup, env)
        # The bridge's Fast DDS profile: an mkstemp file (0600) in the private run directory.
        [profile] = glob.glob(f"{xdg}/embagents/run-*/fastdds-{pid}-*.xml")
        assert re.fullmatch(rf"{xdg}/embagents/run-[0-9a-f]{{8}}/fastdds-{pid}-[a-z0-9_]{{8}}\.xml", profile)
        assert os.stat(profile).st_mode & 0o777 == 0o600
        dead_files = mapped_fastdds_files(pid)
        killed_at = time.monotonic()
        os.kill(pid, signal.SIGKILL)
        arrivals = json.loads(peer.stdout.readline())
        assert any(t > killed_at + 0.5 for t in arrivals), "the flow never recovered"
        # The next incarnation removed what the killed one could not (its DDS segment, its ports):
        # of the files it mapped, none is left without a live owner.
        assert dead_files
        assert clean_zombie_fastdds_segments(min_age=0, names=dead_files) == []
        # The outage: the longest silence on /pong around the kill (pongs come every 50 ms).
        around = [t for t in arrivals if t > killed_at - 0.2]
        recovery = max(b - a for a, b in zip(around, around[1:], strict=False))
        print(f"flow recovered within {recovery:.3f} s of the bridge being killed")
        # Issue bar: 2 s, measured by `embagents bench --only ros_bridge_recovery` (12 kills here:
        # p50 0.37 s, max 0.82 s). The test allows 5 s: CI machines are noisy.
        assert recovery < 5.0
    finally:
        peer.kill()
        peer.communicate()
        sup.send_signal(signal.SIGTERM)
        log, _ = sup.communicate(timeout=30)
    assert sup.returncode == 0, log
    # The run took its files with it (the killed bridge's profile too); none were ever put in /tmp.
    assert not os.path.exists(profile)
    assert sorted(os.listdir(xdg / "embagents")) == ["runs"] and os.listdir(xdg / "embagents" / "runs") == []
    assert not glob.glob(os.path.join(tempfile.gettempdir(), "*fastdds*.xml*"))

def test_a_restarted_bridge_looks_again_for_the_peers_it_had(tmp_path: Path, ros_env: dict[str, str]) -> None:
    import queue
    import threading

    path = tmp_path / "system.py"
    path.write_text(textwrap.dedent(ECHO_SYSTEM))
    sup = subprocess.Popen([sys.executable, "-m", "embagents.cli", "supervise", str(path)],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=ros_env)
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in sup.stdout or ()], daemon=True).start()
    peer = subprocess.Popen([sys.executable, "-c", STREAMER, "60"], stdout=subprocess.PIPE, text=True, env=ros_env)
    seen: list[str] = []
    try:
        assert peer.stdout is not None
        assert peer.stdout.readline().strip() == "FLOWING"
        # SIGKILL: the bridge keeps counting the peer until its DDS lease ends (20 s), as after a
        # lost reply, so its next incarnation looks for a peer that does not answer.
        peer.kill()
        peer.wait()
        os.kill(bridge_pid(sup), signal.SIGKILL)
        while not any("waiting for their periodic announcements" in x for x in seen):
            seen.append(lines.get(timeout=30))
    finally:
        peer.kill()
        sup.send_signal(signal.SIGTERM)
        sup.wait(timeout=30)
    log = "".join(seen)
    for attempt in range(1, REDISCOVER_TRIES + 1):
        assert f"new DDS participant ({attempt} of {REDISCOVER_TRIES})" in log, log
    assert "no ROS peer seen again on /ping, /pong" in log, log
    assert sup.returncode == 0


MANAGER_SYSTEM = '''
import sys
from embagents import Manager, Node, String, System, Topic
from embagents.ros import RosInput, RosOutput

text_in, text_out = Topic("text_in", String), Topic("text_out", String)
io = Node("io", subscribe=[text_in], publish=[text_out])

def echo(state, tick):
    msg = io.latest(text_in)
    if msg is not None and msg.data != state.get("last"):
        state["last"] = msg.data
        io.publish(text_out, String(data=f"{msg.data.upper()} rclpy_here={'rclpy' in sys.modules}"))

system = System(
    [], managers=[Manager(50, name="echo", nodes=[io], handlers=[echo])],
    ros=[RosInput("/text_in", "std_msgs/String"), RosOutput("text_out", ros_type="std_msgs/String")],
)
'''


def test_a_managers_node_talks_to_ros_through_the_bridge_without_rclpy(tmp_path: Path, ros_env: dict[str, str]) -> None:
    out = _run(MANAGER_SYSTEM, tmp_path, ros_env, "text")
    assert re.search(r"GOT 'HELLO \d+ rclpy_here=False'", out), out
