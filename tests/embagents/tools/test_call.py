"""``embagents call``: a component's action in a running system, from another process (examples/vlm.py).

The same action runs from an event of the example (a message on ``look``)."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from embagents.tools.call import parse_args

EXAMPLE = Path(__file__).resolve().parents[3] / "examples" / "vlm.py"


def _cli(*args: str, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "embagents.cli", *args], capture_output=True, text=True,
                          timeout=120, env=env)


def test_arguments_are_json_when_they_parse_else_strings() -> None:
    assert parse_args(["camera", "2.5", "false", '{"a": 1}', "what?"]) == ["camera", 2.5, False, {"a": 1}, "what?"]


def test_describe_from_the_cli_answers_about_the_camera_of_the_running_vlm_example(
        tmp_path: Path, tiny_vlm: tuple[str, str]) -> None:
    for module in ("llama_cpp", "cv2", "skimage"):
        pytest.importorskip(module)
    env = {**os.environ, "EMBAGENTS_RUNS_DIR": str(tmp_path / "runs"), "EMBAGENTS_KEEP_RUNNING": "1",
           "EMBAGENTS_VLM_MODEL": tiny_vlm[0], "EMBAGENTS_VLM_HANDLER": "llava15"}
    proc = subprocess.Popen([sys.executable, "-m", "embagents.cli", "supervise", str(EXAMPLE)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in proc.stdout or ()], daemon=True).start()

    def next_answer() -> str:
        while not (line := lines.get(timeout=60)).startswith("A: "):
            pass
        return line[3:].strip()

    try:
        assert next_answer()  # the asker's own question, about the first frame
        out = _cli("call", "vlm", "describe", "camera", "What is on the table?", env=env)
        assert out.returncode == 0, out.stderr
        assert out.stdout.startswith("vlm.describe -> '")
        assert next_answer() == out.stdout.strip()[len("vlm.describe -> '"):-1]  # published on answer too
        assert _cli("publish", "look", "look", env=env).returncode == 0  # the event calls describe
        assert next_answer()

        bad = _cli("call", "vlm", "describe", "question", env=env)
        assert bad.returncode == 1
        assert "vlm.describe failed" in bad.stderr and "describe needs one of its image inputs (camera)" in bad.stderr
        bad = _cli("call", "vlm", "fly", env=env)
        assert bad.returncode == 1 and "component 'vlm' (VLM) has no action 'fly'; its actions:" in bad.stderr
        assert "describe" in bad.stderr
        bad = _cli("call", "nobody", "describe", env=env)
        assert bad.returncode == 1 and "has no component 'nobody'; its components: asker, camera, printer, vlm" in bad.stderr
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=30)
    assert proc.returncode == 0
