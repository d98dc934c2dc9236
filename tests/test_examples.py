"""Every example system passes `embagents check`; the chat-memory example keeps its conversation."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).parents[1] / "examples"


@pytest.mark.parametrize("name", ["chat.py", "chat_memory.py", "ros_chat.py"])
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
