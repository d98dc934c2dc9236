"""``embagents publish``: a message on a topic of a running system, from another process."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
from pathlib import Path

from tests.embagents.cli.test_supervise import _supervise, _write


def _cli(*args: str, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "embagents.cli", *args], capture_output=True, text=True,
                          timeout=60, env=env)


def test_a_second_question_reaches_the_running_system_and_bad_ones_are_named(tmp_path: Path, tiny_gguf: str) -> None:
    env = {**os.environ, "EMBAGENTS_RUNS_DIR": str(tmp_path / "runs")}
    proc = _supervise(_write(tmp_path, tiny_gguf), KEEP="1", EMBAGENTS_RUNS_DIR=env["EMBAGENTS_RUNS_DIR"])
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in proc.stdout or ()], daemon=True).start()

    def answers(n: int) -> list[str]:
        """Lines up to the n-th finished answer (the printer's last chunk of each ends with True)."""
        seen: list[str] = []
        while sum(x.startswith("CHUNK") and x.rstrip().endswith("True") for x in seen) < n:
            seen.append(lines.get(timeout=60))
        return seen

    try:
        answers(1)  # the asker's own question
        out = _cli("publish", "text_in", "hello robot", env=env)
        assert out.returncode == 0, out.stderr
        assert out.stdout.startswith("published String on text_in (run ")
        assert any(x.startswith("CHUNK") for x in answers(1))  # the llm answered the published question

        bad = _cli("publish", "no_such_topic", "x", env=env)
        assert bad.returncode == 1
        assert "has no topic 'no_such_topic'; its topics: system_stop, text_in, text_out" in bad.stderr
        bad = _cli("publish", "text_in", "--fields", '{"colour": "blue"}', env=env)
        assert bad.returncode == 1 and "topic 'text_in': String has no field 'colour'" in bad.stderr
        assert "fields of String: data (str)" in bad.stderr
        bad = _cli("publish", "text_in", "--fields", "{not json", env=env)
        assert bad.returncode == 1 and "--fields is not JSON" in bad.stderr
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=30)
    assert proc.returncode == 0
    none = _cli("publish", "text_in", "hi", env=env)
    assert none.returncode == 1 and "no live embagents run found" in none.stderr
