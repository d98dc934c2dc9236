"""Every example system passes `embagents check`; the chat-memory example keeps its conversation;
the vision example finds the astronaut's face and cuts two motion clips."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).parents[1] / "examples"


@pytest.mark.parametrize("name", ["chat.py", "chat_memory.py", "ros_chat.py", "vision.py", "memory.py"])
def test_example_systems_check_clean(name: str) -> None:
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "check", str(EXAMPLES / name)],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    assert out.stdout.startswith("OK:")


def test_chat_memory_survives_a_sigkill_of_the_llm() -> None:
    pytest.importorskip("llama_cpp", reason="the example runs SmolLM2 (pip install 'embagents[llm]')")
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "supervise", str(EXAMPLES / "chat_memory.py")],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr[-3000:]
    lines = out.stdout.splitlines()
    assert lines[0] == "Q: My favourite colour is blue." and lines[1], out.stdout
    killed = re.fullmatch(r"\[demo\] SIGKILLed the llm \(pid (\d+)\); its supervisor starts a new one", lines[2])
    restored = re.fullmatch(r"\[demo\] the new llm \(pid (\d+)\) restored 2 messages of history", lines[3])
    assert killed and restored and killed[1] != restored[1], out.stdout
    assert lines[4] == "Q: What is my favourite colour?" and lines[5], out.stdout
    # The supervisor saw exactly the one SIGKILL the demo sent, and restarted that llm.
    crashes = [x for x in out.stderr.splitlines() if "crashed root/llm" in x]
    assert len(crashes) == 1 and f"pid={killed[1]}" in crashes[0] and "reason=killed" in crashes[0], out.stderr
    # A fresh start says so; only the restart restored a lifecycle state.
    said = [x.split("supervisor.lifecycle: ")[1] for x in out.stderr.splitlines() if "supervisor.lifecycle: " in x]
    assert said == ["[llm] activated", "[demo] activated", "[llm] lifecycle restored to active"], out.stderr


def test_vision_example_finds_the_face_and_writes_the_image_and_clips(tmp_path: Path) -> None:
    for module in ("onnxruntime", "cv2", "skimage", "supervision"):
        pytest.importorskip(module, reason="the example needs the vision extra (pip install 'embagents[vision]')")
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "supervise", str(EXAMPLES / "vision.py")],
                         capture_output=True, text=True, timeout=180, env={**os.environ, "EMBAGENTS_VISION_OUT": str(tmp_path)})
    assert out.returncode == 0, out.stdout + out.stderr[-3000:]
    found = [re.fullmatch(r"detection: face (0\.9\d\d|1\.000) box \((\d+), (\d+), (\d+), (\d+)\)", x)
             for x in out.stdout.splitlines() if x.startswith("detection:")]
    assert len(found) >= 10 and all(found), out.stdout
    x1, y1, x2, y2 = (int(v) for v in found[0].groups()[1:])  # the first frame: her face, top middle
    assert 150 < x1 < 200 and 20 < y1 < 60 and 240 < x2 < 290 and 130 < y2 < 180, out.stdout
    assert (tmp_path / "annotated.png").stat().st_size > 10_000
    clips = sorted(tmp_path.glob("motion_clip_*.mp4"))
    assert [c.name for c in clips] == ["motion_clip_1.mp4", "motion_clip_2.mp4"], out.stdout
    assert out.stdout.splitlines()[-1] == f"done: 2 clips in {tmp_path}", out.stdout


def test_memory_example_answers_where_the_cup_was_from_a_tool_call(tmp_path: Path) -> None:
    for module in ("llama_cpp", "onnxruntime", "apsw", "sqlite_vec", "tokenizers"):
        pytest.importorskip(module, reason="the example needs the llm and memory extras")
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "supervise", str(EXAMPLES / "memory.py")],
                         capture_output=True, text=True, timeout=240,
                         env={**os.environ, "EMBAGENTS_MEMORY_DB": str(tmp_path / "memory.db")})
    assert out.returncode == 0, out.stdout + out.stderr[-3000:]
    lines = out.stdout.splitlines()
    assert "[base] at (4.0, 2.0): sees cup, bottle; note: the kitchen table" in lines, out.stdout
    assert lines[-4] == "Q: Where did you see the cup?", out.stdout
    assert lines[-3] == 'tool call: locate({"what": "cup"})', out.stdout
    assert re.fullmatch(r"tool result: I last saw cup \d+ s ago at x=4\.0, y=2\.0, near the kitchen table", lines[-2])
    assert lines[-1].startswith("A: ") and "kitchen table" in lines[-1], out.stdout
    # The call crossed processes: the events actor ran it in memory's actor.
    assert "[_events] INFO embagents.events: tool call memory.locate(what='cup')" in out.stderr
