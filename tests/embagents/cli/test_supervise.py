"""`embagents supervise system.py` end to end, in a subprocess, with a tiny real GGUF model."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import psutil
import pytest

CHAT = '''
import os, sys
from embagents.components import LLM, Component, LLMConfig
from embagents.system import SYSTEM_STOP
from embagents.models import LlamaModel, LocalModelClient
from embagents.msgs import StreamingString, String
from embagents.system import System
from embagents.topic import Topic

text_in, text_out, stop = Topic("text_in", String), Topic("text_out", StreamingString, queue_size=1000, keep="all"), Topic(SYSTEM_STOP, String)


class Asker(Component):
    allowed_outputs = {"Required": [String]}

    def on_activate(self):
        self.publish(text_in, String(data="Say something"))


class Printer(Component):
    allowed_inputs = {"Required": [StreamingString]}
    allowed_outputs = {"Optional": [String]}

    def _execution_step(self, **inputs):
        chunk = inputs["text_out"]
        print(f"CHUNK {chunk.data!r} {chunk.done}", flush=True)
        if chunk.done and not os.environ.get("KEEP"):
            self.publish(stop, String(data="done"))


model = LlamaModel(name="tiny", local_model_path=MODEL, warmup=False)
system = System(
    [
        Printer(name="printer", inputs=[text_out], outputs=[stop], trigger=text_out),
        LLM(name="llm", inputs=[text_in], outputs=[text_out], model_client=LocalModelClient(model),
            config=LLMConfig(stream=True, temperature=0.0, max_new_tokens=8)),
        Asker(name="asker", outputs=[text_in], trigger=None),
    ],
    models=[model],
)
'''


def _write(tmp_path: Path, model: str) -> str:
    path = tmp_path / "chat_system.py"
    path.write_text(textwrap.dedent(CHAT).replace("MODEL", repr(model)))
    return str(path)


def _supervise(path: str, **env: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "embagents.cli", "supervise", path],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env={**os.environ, **env},
    )


def test_supervise_streams_an_answer_and_stops_cleanly(tmp_path: Path, tiny_gguf: str) -> None:
    proc = _supervise(_write(tmp_path, tiny_gguf))
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 0, out
    chunks = [line for line in out.splitlines() if line.startswith("CHUNK")]
    assert len(chunks) >= 2 and chunks[-1].endswith("True"), out
    assert "[llm]" not in out or "Traceback" not in out


def test_sigterm_stops_everything_with_exit_code_0(tmp_path: Path, tiny_gguf: str) -> None:
    proc = _supervise(_write(tmp_path, tiny_gguf), KEEP="1")
    assert proc.stdout is not None
    deadline = time.monotonic() + 60
    for line in proc.stdout:
        if "running" in line or time.monotonic() > deadline:
            break
    children = psutil.Process(proc.pid).children(recursive=True)
    assert len(children) >= 5  # fork server, model actor, three components
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=30) == 0
    gone, alive = psutil.wait_procs(children, timeout=5)
    assert alive == []


def test_a_system_with_problems_is_not_started(tmp_path: Path) -> None:
    path = tmp_path / "bad.py"
    path.write_text(textwrap.dedent('''
        from embagents.components import LLM
        from embagents.models import LlamaModel, LocalModelClient
        from embagents.msgs import Image, StreamingString
        from embagents.system import System
        from embagents.topic import Topic
        m = LlamaModel(name="m", local_model_path="/nonexistent/model.gguf")
        system = System([LLM(name="llm", inputs=[Topic("cam", Image)], outputs=[Topic("o", StreamingString)],
                             model_client=LocalModelClient(m))], models=[m])
    '''))
    proc = subprocess.run(
        [sys.executable, "-m", "embagents.cli", "supervise", str(path)], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 1
    assert "component 'llm'" in proc.stderr and "Traceback" not in proc.stderr


def test_a_missing_model_file_is_named_with_the_fix(tmp_path: Path) -> None:
    path = _write(tmp_path, "/nonexistent/model.gguf")
    proc = subprocess.run(
        [sys.executable, "-m", "embagents.cli", "supervise", path], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 1
    assert "/nonexistent/model.gguf" in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.parametrize("content, needle", [("x = = 1", "SyntaxError"), ("x = 1", "System(")])
def test_a_malformed_system_file_gets_a_clear_error(tmp_path: Path, content: str, needle: str) -> None:
    path = tmp_path / "broken.py"
    path.write_text(content)
    proc = subprocess.run(
        [sys.executable, "-m", "embagents.cli", "supervise", str(path)], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 1 and needle in proc.stderr and "Traceback" not in proc.stderr


def _supervise_once(path: str, **env: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "embagents.cli", "supervise", path],
                          capture_output=True, text=True, timeout=60, env={**os.environ, **env})


def test_every_components_problems_are_reported_as_check_reports_them(tmp_path: Path) -> None:
    path = tmp_path / "bad.py"
    path.write_text(textwrap.dedent('''
        from embagents.components import LLM
        from embagents.models import LlamaModel, LocalModelClient
        from embagents.msgs import Image, StreamingString
        from embagents.system import System
        from embagents.topic import Topic
        m = LlamaModel(name="m", local_model_path="/nonexistent/model.gguf")
        cam, out = Topic("cam", Image), Topic("o", StreamingString)
        system = System([LLM(name="first", inputs=[cam], outputs=[out], model_client=LocalModelClient(m)),
                         LLM(name="second", inputs=[cam], outputs=[out], model_client=LocalModelClient(m))],
                        models=[m], external=[cam])
    '''))
    proc = _supervise_once(str(path))
    check = subprocess.run([sys.executable, "-m", "embagents.cli", "check", str(path)],
                           capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    reported = [line for line in proc.stderr.splitlines() if line.startswith("error: [")]
    assert reported == [line for line in check.stdout.splitlines() if line.startswith("error: [")]
    for who in ("component 'first'", "component 'second'", "model 'm'"):
        assert any(who in line for line in reported), (who, reported)
    assert proc.stderr.rstrip().endswith(f"{path}: {len(reported)} errors; not starting")


def test_a_directory_gets_a_system_file_to_pass(tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "embagents.cli", "supervise", "examples"], capture_output=True,
                          text=True, timeout=60, cwd=Path(__file__).parents[3])
    assert proc.returncode == 1
    assert "/examples: is a directory, not a system file; pass one of its system files, e.g. `examples/" \
        in proc.stderr and "examples/chat.py" in proc.stderr and "Traceback" not in proc.stderr


def test_an_unreachable_model_hub_is_one_line(tmp_path: Path) -> None:
    pytest.importorskip("huggingface_hub", reason="huggingface_hub not installed")
    proc = _supervise_once(_write(tmp_path, "Qwen/Qwen3-0.6B-GGUF"), HF_ENDPOINT="http://127.0.0.1:9",
                           HF_HOME=str(tmp_path / "hf"))
    assert proc.returncode == 1, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("embagents supervise: Cannot reach the Hugging Face hub to fetch 'Qwen/Qwen3-0.6B-GGUF")
    assert "Traceback" not in proc.stderr and "Retrying" not in proc.stderr


QUIET = '''
import logging
from embagents.components import Component
from embagents.system import SYSTEM_STOP
from embagents.msgs import String
from embagents.system import System
from embagents.topic import Topic

stop = Topic(SYSTEM_STOP, String)
log = logging.getLogger("answerer")


class Answerer(Component):
    allowed_outputs = {"Required": [String]}

    def _execution_step(self, **_):
        if not getattr(self, "said", False):
            self.said = True
            log.info("an info line of the answerer")
            log.warning("a warning of the answerer")
            print("ANSWER 42", flush=True)
        self.publish(stop, String(data="done"))  # again until the root hears it


system = System([Answerer(name="answerer", outputs=[stop], trigger=5.0)])
'''


def test_quiet_leaves_the_answer_on_stdout_and_only_warnings_on_stderr(tmp_path: Path) -> None:
    path = tmp_path / "quiet.py"
    path.write_text(QUIET)
    loud = subprocess.run([sys.executable, "-m", "embagents.cli", "supervise", str(path)],
                          capture_output=True, text=True, timeout=60)
    assert loud.returncode == 0 and "an info line of the answerer" in loud.stderr and " INFO " in loud.stderr
    quiet = subprocess.run([sys.executable, "-m", "embagents.cli", "supervise", "--quiet", str(path)],
                           capture_output=True, text=True, timeout=60)
    assert quiet.returncode == 0, quiet.stderr
    assert quiet.stdout == "ANSWER 42\n"
    assert "a warning of the answerer" in quiet.stderr  # warnings still show, from the actors too
    assert " INFO " not in quiet.stderr and "running" not in quiet.stderr, quiet.stderr


def test_an_import_that_never_returns_is_said_and_ctrl_c_is_one_line(tmp_path: Path) -> None:
    path = tmp_path / "hangs.py"
    path.write_text("import time\ntime.sleep(600)  # a driver that never answers\n")
    proc = subprocess.Popen([sys.executable, "-m", "embagents.cli", "supervise", str(path)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline()  # blocks until the notice (the import itself never returns)
        assert line.startswith("embagents: still importing hangs.py...") and "Ctrl-C stops" in line
        proc.send_signal(signal.SIGINT)
        rest = proc.stderr.read()
        assert proc.wait(timeout=30) == 130
    finally:
        proc.kill()
        proc.wait()
    assert rest.strip() == f"embagents supervise: stopped (Ctrl-C) while importing {path}; nothing was started"
