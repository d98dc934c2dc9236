"""`embagents check`: every wiring problem of a system.py, each naming its component."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from embagents.check import Problem, check_file, check_system, errors
from embagents.cli import main

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

HEADER = """\
from embagents.components import LLM, Component, LLMConfig
from embagents.events import Event, Fallback, call, on, reconfigure, restart, switch_model_client
from embagents.msgs import Image, StreamingString, String
from embagents.system import System
from embagents.topic import Topic


class Client:
    name = "local"

    def chat_stream(self, messages, **options):
        yield {"delta": "ok"}
        yield {"done": True, "finish_reason": "stop", "tool_calls": None}


class Camera(Component):
    allowed_outputs = {"Required": [Image]}

    def _execution_step(self, **inputs):
        pass


class Detector(Component):
    allowed_inputs = {"Required": [Image]}
    allowed_outputs = {"Required": [String]}

    def _execution_step(self, **inputs):
        pass


image = Topic("camera/image", Image)
labels = Topic("labels", String)
answer = Topic("answer", String)
"""

GOOD = """
camera = Camera(name="camera", outputs=[image], trigger=15.0)
detector = Detector(name="detector", inputs=[image], outputs=[labels], trigger=image)
llm = LLM(name="llm", inputs=[labels], outputs=[answer], model_client=Client())
system = System([camera, detector, llm])
"""


def write(tmp_path, body: str):
    path = tmp_path / "system.py"
    path.write_text(HEADER + textwrap.dedent(body))
    return str(path)


def check(tmp_path, body: str) -> list[Problem]:
    system, problems = check_file(write(tmp_path, body))
    return problems


def only(problems: list[Problem], code: str) -> Problem:
    found = [p for p in problems if p.code == code]
    assert len(found) == 1, problems
    return found[0]


def test_clean_system_has_no_problems(tmp_path, capsys):
    assert check(tmp_path, GOOD) == []
    assert main(["check", str(tmp_path / "system.py")]) == 0
    assert capsys.readouterr().out.strip() == "OK: 3 components, 3 topics"


def test_wrong_input_type(tmp_path):
    problems = check(tmp_path, GOOD.replace("inputs=[image], outputs=[labels]", "inputs=[image, labels], outputs=[labels]"))
    p = only(problems, "wrong-input-type")
    assert p.component == "detector" and "'detector'" in p.message and "'labels'" in p.message
    assert "allowed input types: Image" in p.message and p.level == "error"


def test_missing_required_input(tmp_path):
    problems = check(tmp_path, GOOD.replace("LLM(name=\"llm\", inputs=[labels]", "LLM(name=\"llm\", inputs=[]"))
    p = only(problems, "missing-input")
    assert p.component == "llm" and "'llm'" in p.message and "String" in p.message


def test_duplicate_names_anywhere_in_the_list(tmp_path):
    body = GOOD.replace('LLM(name="llm"', 'LLM(name="camera"')
    p = only(check(tmp_path, body), "duplicate-component")
    assert p.component == "camera" and "'camera' is used by 2 components (#1 Camera, #3 LLM)" in p.message


def test_two_components_under_simple_one_for_one_fail_the_check_as_they_would_fail_supervise(tmp_path, capsys):
    # `check` builds the tree `supervise` runs: what one refuses, the other does.
    from embagents.supervision import build_spec
    from embagents.system import load_system

    body = GOOD.replace("System([camera, detector, llm])",
                        'System([camera, detector], supervision={"strategy": "simple_one_for_one"})')
    p = only(check(tmp_path, body), "supervision")
    assert "simple_one_for_one takes exactly one child spec" in p.message and "got 2 (camera, detector)" in p.message
    assert "use one_for_one, one_for_all or rest_for_one" in p.message and p.level == "error"
    path = str(tmp_path / "system.py")
    assert main(["check", path]) == 1
    with pytest.raises(ValueError, match="exactly one child spec"):
        build_spec(load_system(path), path)


def test_a_model_and_a_component_of_one_name_fail_the_check(tmp_path):
    # Both become children of the root supervisor: the tree refuses two children of one id.
    body = GOOD.replace("system = System([camera, detector, llm])", """
from embagents.models import LlamaModel, LocalModelClient
model = LlamaModel(name="detector", local_model_path=__file__)
talker = LLM(name="talker", inputs=[labels], outputs=[answer], model_client=LocalModelClient(model))
system = System([camera, detector, talker], models=[model])
""")
    p = only(check(tmp_path, body), "supervision")
    assert "duplicate child ids: detector" in p.message and "each model and component is a child" in p.message


@pytest.mark.parametrize(("policy", "needle"), [
    ("{'strategy': 'all_for_none'}", "strategy must be one of one_for_one"),
    ("{'intensity': -1}", "intensity must be an integer >= 0"),
    ("{'intensity': True}", "intensity must be an integer >= 0"),
    ("{'period': 0}", "period must be > 0 seconds"),
    ("{'period': '5'}", "period must be > 0 seconds"),
])
def test_bad_supervision_values_are_check_problems(tmp_path, policy, needle):
    p = only(check(tmp_path, GOOD.replace("System([camera, detector, llm])",
                                          f"System([camera, detector, llm], supervision={policy})")), "supervision")
    assert needle in p.message and policy.strip("{}") in p.message


def test_unknown_topic_is_a_warning_and_external_silences_it(tmp_path, capsys):
    body = GOOD.replace("system = System([camera, detector, llm])", "system = System([detector, llm])")
    p = only(check(tmp_path, body), "unknown-topic")
    assert p.level == "warning" and p.component == "detector" and "'camera/image'" in p.message
    assert main(["check", str(tmp_path / "system.py")]) == 0
    out = capsys.readouterr().out
    assert "warning: [unknown-topic] component 'detector'" in out and "(1 warning)" in out
    body = body.replace("System([detector, llm])", "System([detector, llm], external=[image])")
    assert check(tmp_path, body) == []


def test_topic_used_with_two_types(tmp_path):
    body = GOOD.replace('answer = Topic("answer", String)', "") + '\nother = Topic("labels", Image)\n'
    body = body.replace("outputs=[answer]", "outputs=[Topic('answer', String)]")
    body += 'system = System([camera, detector, llm, Detector(name="viewer", inputs=[other], outputs=[Topic("x", String)])])\n'
    body = body.replace("system = System([camera, detector, llm])\n", "")
    p = only(check(tmp_path, body), "topic-type-conflict")
    assert p.component == "detector" and "'labels'" in p.message
    assert "String as output of component 'detector'" in p.message and "Image as input of component 'viewer'" in p.message


def test_trigger_not_among_inputs(tmp_path):
    body = GOOD.replace("trigger=image)", "trigger=labels)")
    p = only(check(tmp_path, body), "trigger-not-input")
    assert p.component == "detector" and "trigger topic 'labels' is not one of its inputs (camera/image)" in p.message


def test_event_action_naming_unknown_component(tmp_path):
    body = GOOD.replace("system = System([camera, detector, llm])", """
stop_said = Event("stop_said", on(answer).field("data").contains("stop"))
system = System([camera, detector, llm], events={stop_said: [restart("navigation"), restart(camera)]})
""")
    problems = check(tmp_path, body)
    p = only(problems, "unknown-component")
    assert p.component == "navigation" and "event 'stop_said'" in p.message
    assert "components: camera, detector, llm" in p.message


def test_event_actions_checked_against_the_component(tmp_path):
    body = GOOD.replace("system = System([camera, detector, llm])", """
ev = Event("ev", on(answer).field("data") == "x")
system = System([camera, detector, llm], events={ev: [reconfigure(llm, {"temprature": 0.1}),
                                                    call(llm, "forget"), switch_model_client("cloud", llm)]})
""")
    problems = check(tmp_path, body)
    assert "unknown config key 'temprature'" in only(problems, "bad-config").message
    assert "component 'llm' (LLM) has no method 'forget'" in only(problems, "bad-action").message
    assert "no model client 'cloud'; known: local" in only(problems, "unknown-client").message
    assert {p.component for p in problems} == {"llm"}


def test_fallback_switching_to_unknown_client(tmp_path):
    body = GOOD.replace("model_client=Client())", "model_client=Client(), fallback=Fallback(on_algorithm_fail=switch_model_client('cloud')))")
    p = only(check(tmp_path, body), "unknown-client")
    assert p.component == "llm" and "known clients: local" in p.message


def test_all_problems_of_the_file_are_reported(tmp_path, capsys):
    body = """
camera = Camera(name="camera", outputs=[labels], trigger=15.0)
detector = Detector(name="detector", inputs=[labels], outputs=[labels], trigger=image)
llm = LLM(name="llm", inputs=[image], outputs=[answer], model_client=Client(), config=LLMConfig(stream=True))
system = System([camera, detector, llm])
"""
    problems = check(tmp_path, body)
    by_component = {(p.component, p.code) for p in errors(problems)}
    assert {("camera", "wrong-output-type"), ("camera", "missing-output"), ("detector", "wrong-input-type"),
            ("detector", "missing-input"), ("detector", "trigger-not-input"), ("llm", "wrong-input-type"),
            ("llm", "bad-config")} <= by_component
    assert all(p.component and f"'{p.component}'" in p.message for p in problems)
    assert main(["check", str(tmp_path / "system.py")]) == 1
    assert capsys.readouterr().err.startswith(f"{len(errors(problems))} errors")


def test_ros_declarations_provide_and_consume_topics(tmp_path):
    body = """
from embagents.ros import RosInput, RosOutput
detector = Detector(name="detector", inputs=[image], outputs=[labels], trigger=image)
system = System([detector], ros=[RosInput("/camera/image", "sensor_msgs/Image"),
                                 RosOutput("labels", ros_type="geometry_msgs/Twist")])
"""
    problems = check(tmp_path, body)
    assert [p.code for p in problems] == ["ros"]  # camera/image is provided by ROS: no unknown-topic
    assert "RosOutput 'labels'" in problems[0].message and "cannot carry String" in problems[0].message


def test_load_error_is_one_problem_naming_the_line(tmp_path, capsys):
    path = write(tmp_path, GOOD.replace("system = System", 'sound = Topic("sound", "Audoi")\nsystem = System'))
    line = open(path).read().splitlines().index('sound = Topic("sound", "Audoi")') + 1
    _, problems = check_file(path)
    assert [p.code for p in problems] == ["load-error"]
    assert f"system.py:{line}: TopicError" in problems[0].message and "'Audoi'" in problems[0].message
    assert main(["check", path]) == 1
    assert "load-error" in capsys.readouterr().out


def test_check_system_on_objects():
    from embagents.components import Component
    from embagents.msgs import String
    from embagents.system import System
    from embagents.topic import Topic

    t = Topic("t", String)
    a, b = Component(name="a", outputs=[t]), Component(name="b", inputs=[t], trigger=t)
    assert check_system(System([a, b])) == []
    assert str(Problem("a", "x", "msg", "warning")) == "warning: [x] msg"


@pytest.mark.parametrize(("body", "code", "needle"), [(GOOD, 0, "OK: 3 components, 3 topics"),
                                                      (GOOD.replace("trigger=image)", "trigger=labels)"), 1,
                                                       "error: [trigger-not-input] component 'detector'")])
def test_cli_as_a_module(tmp_path, body, code, needle):
    path = write(tmp_path, body)
    env = {**os.environ, "PYTHONPATH": ROOT + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.run([sys.executable, "-m", "embagents.cli", "check", path],
                          capture_output=True, text=True, env=env, timeout=60)
    assert proc.returncode == code, proc.stderr
    assert needle in proc.stdout


def test_cli_usage_errors(capsys):
    assert main([]) == 2
    assert main(["check"]) == 2
    assert main(["check", "/nonexistent/system.py"]) == 1
    assert "no such file" in capsys.readouterr().out


def test_a_model_file_that_is_not_there_fails_the_check_naming_path_and_fix(tmp_path, capsys):
    body = """
from embagents.models import LlamaModel, LocalModelClient
model = LlamaModel(name="m", local_model_path="/nonexistent/model.gguf")
llm = LLM(name="llm", inputs=[answer], outputs=[labels], model_client=LocalModelClient(model))
system = System([llm], models=[model], external=[answer])
"""
    problem = only(check(tmp_path, body), "model-file")
    assert problem.level == "error"
    assert "model 'm': Model file not found: '/nonexistent/model.gguf'" in problem.message
    assert "default_llm_path()" in problem.message
    assert main(["check", str(tmp_path / "system.py")]) == 1
    assert capsys.readouterr().err.strip() == "1 error"


def test_a_system_of_one_component_is_counted_in_the_singular(tmp_path, capsys):
    write(tmp_path, 'camera = Camera(name="camera", outputs=[image], trigger=15.0)\nsystem = System([camera])\n')
    assert main(["check", str(tmp_path / "system.py")]) == 0
    assert capsys.readouterr().out.strip() == "OK: 1 component, 1 topic"


def test_a_managers_node_topics_count_in_the_check() -> None:
    from embagents.manager import Manager, Node
    from embagents.msgs import Image, String
    from embagents.system import System
    from embagents.topic import Topic

    heard, said = Topic("heard", String), Topic("said", String)
    node = Node("io", subscribe=[heard, Topic("said", Image)], publish=[said])
    problems = check_system(System([], managers=[Manager(10, name="boss", nodes=[node])]))
    by_code = {p.code: p for p in problems}
    assert by_code["unknown-topic"].message.startswith("manager 'boss': node 'io' subscribes to 'heard' (String), "
                                                       "which nothing in this system publishes")
    assert "topic 'said' is used with 2 message types" in by_code["topic-type-conflict"].message


def test_a_handshake_on_a_topic_no_node_subscribes_to_is_an_error() -> None:
    from embagents.manager import HandshakeRule, Manager
    from embagents.msgs import Image
    from embagents.system import System
    from embagents.topic import Topic

    image = Topic("camera/image_raw", Image)
    boss = Manager(10, name="boss", handshake=[HandshakeRule.first_message(image)])
    [problem] = check_system(System([], managers=[boss], external=[image]))
    assert problem.level == "error" and problem.message == (
        "manager 'boss': handshake rule 'first_message_on_camera_image_raw' waits for a message on 'camera/image_raw', "
        "which none of its nodes subscribes to (it would never hold); add the topic to a Node(subscribe=[...]) of "
        "the manager")


CUDA_AT_IMPORT = """\
import ctypes
import os

from embagents.components import Component
from embagents.system import System

# Stands in for `model = Net().cuda()`: what that leaves in the process is the CUDA driver library.
driver = ctypes.CDLL(os.path.join(os.path.dirname(os.path.abspath(__file__)), "libcuda.so.1"))


class Gpu(Component):
    def on_configure(self):
        self.net = "Net().cuda() belongs here: it runs in the component's own process"


system = System([Gpu(name="gpu", start_method="spawn")])
"""


def _stand_in_driver(folder) -> None:
    """A real shared library (libm) under the CUDA driver's name: loading it maps `libcuda.so.1`."""
    import ctypes.util
    import shutil

    libm = next(line.split()[-1] for line in open("/proc/self/maps") if "/libm.so" in line or "/libm-" in line)
    assert ctypes.util.find_library("m")
    shutil.copy(libm, os.path.join(folder, "libcuda.so.1"))


@pytest.mark.parametrize("command", ["check", "supervise"])
def test_a_system_file_that_initialises_cuda_in_the_root_is_refused_naming_the_line_and_the_fix(tmp_path, command):
    _stand_in_driver(tmp_path)
    path = write(tmp_path, CUDA_AT_IMPORT)
    env = {**os.environ, "PYTHONPATH": ROOT + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.run([sys.executable, "-m", "embagents.cli", command, path],
                          capture_output=True, text=True, env=env, timeout=60)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 1, out
    line = len(HEADER.splitlines()) + 8  # write() puts HEADER first
    assert f"[cuda-in-root] {path}:{line}: `driver = ctypes.CDLL(" in out
    assert "the CUDA driver (libcuda.so.1) is loaded" in out
    assert "on_configure" in out and 'start_method="spawn"' in out


def test_gpu_work_inside_on_configure_passes_the_check(tmp_path):
    path = write(tmp_path, CUDA_AT_IMPORT.replace("driver = ctypes.CDLL", "def load(): return ctypes.CDLL"))
    system, problems = check_file(path)
    assert [p.code for p in problems] == []
    assert system is not None and system.components[0].start_method == "spawn"


def test_cuda_detection_reads_the_process_maps():
    from embagents.check import cuda_in_process

    maps = ("55d0-55d1 r--p 0 08:01 11 /usr/bin/python3.11\n"
            "7f00-7f01 r-xp 0 08:01 12 /usr/lib/x86_64-linux-gnu/libcuda.so.550.54.15\n")
    assert cuda_in_process(lambda: maps) == "the CUDA driver (libcuda.so.550.54.15) is loaded in this process"
    assert cuda_in_process(lambda: maps.replace("libcuda", "libcudart")) is None  # the runtime alone: no context
    assert cuda_in_process() is None  # this test process has none


def test_a_bad_start_method_is_a_component_problem(tmp_path):
    path = write(tmp_path, CUDA_AT_IMPORT.replace("driver = ctypes.CDLL", "def load(): return ctypes.CDLL")
                 .replace('start_method="spawn"', 'start_method="forkserver"'))
    _, problems = check_file(path)
    assert [p.code for p in problems] == ["bad-start-method"]


def test_a_model_whose_backend_is_not_installed_names_the_package_and_the_extra(tmp_path):
    # examples/chat.py in a Python where llama_cpp cannot be found (the llm extra left out), as the examples'
    # tests hide a module: nothing is uninstalled.
    from tests.helpers import hide_modules

    env = {**os.environ, "PYTHONPATH": ROOT + os.pathsep + os.environ.get("PYTHONPATH", "")}
    example = os.path.join(ROOT, "examples", "chat.py")
    proc = subprocess.run([sys.executable, "-m", "embagents.cli", "check", example], capture_output=True, text=True,
                          env=hide_modules(tmp_path / "hide", ["llama_cpp"], env), timeout=120)
    assert proc.returncode == 1, proc.stdout
    assert ("error: [missing-backend] model 'smollm2' (LlamaModel) needs llama-cpp-python (module llama_cpp), "
            "which is not installed") in proc.stdout
    assert "pip install 'embagents[llm]'" in proc.stdout
    ok = subprocess.run([sys.executable, "-m", "embagents.cli", "check", example], capture_output=True, text=True,
                        env=env, timeout=120)
    assert ok.returncode == 0 and "missing-backend" not in ok.stdout, ok.stdout  # installed here: no problem


def test_a_topic_published_by_an_event_action_counts_as_published(tmp_path):
    problems = check(tmp_path, """
        from embagents.events import publish
        go = Topic("go", String)
        llm = LLM(name="llm", inputs=[go], outputs=[answer], model_client=Client())
        ev = Event("asked", on(answer).field("data") == "again")
        system = System([llm], events={ev: publish(go, String("again"))}, external=[answer])
    """)
    assert [p for p in problems if p.code == "unknown-topic"] == [], problems


def test_a_custom_component_with_inputs_and_no_trigger_warns_that_it_never_runs(tmp_path):
    problems = check(tmp_path, """
        camera = Camera(name="camera", outputs=[image], trigger=15.0)
        detector = Detector(name="detector", inputs=[image], outputs=[labels], trigger=None)
        llm = LLM(name="llm", inputs=[labels], outputs=[answer], model_client=Client())
        system = System([camera, detector, llm])
    """)
    p = only(problems, "never-runs")
    assert p.level == "warning" and p.component == "detector" and "trigger=camera/image" in p.message


def test_additional_model_clients_is_refused_naming_extra_clients(tmp_path):
    problems = check(tmp_path, GOOD + "llm.additional_model_clients = {'backup': Client()}\n")
    p = only(problems, "load-error")
    assert "additional_model_clients does nothing here" in p.message and "extra_clients=" in p.message
