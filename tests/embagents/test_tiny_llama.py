"""The tiny test GGUF (tests/embagents/tiny_llama.py): small, loads fast, tokenizes, cached and seeded."""

from __future__ import annotations

import os
import time

import pytest

from tests.embagents.tiny_llama import make_tiny_llama_gguf

pytestmark = pytest.mark.llama_in_process  # see tests/conftest.py


def test_tiny_gguf_is_small_loads_fast_and_tokenizes(tiny_gguf: str) -> None:
    llama_cpp = pytest.importorskip("llama_cpp", reason="llama-cpp-python not installed")
    size = os.path.getsize(tiny_gguf)
    assert 200_000 < size < 1_000_000
    start = time.perf_counter()
    llm = llama_cpp.Llama(tiny_gguf, n_ctx=256, verbose=False)
    load_s = time.perf_counter() - start
    try:
        assert load_s < 2.0, f"tiny model took {load_s:.3f} s to load"
        assert 256 < llm.n_vocab() < 500
        assert "<|im_start|>" in llm.metadata["tokenizer.chat_template"]
        text = "hello robot, open the door!\n"
        tokens = llm.tokenize(text.encode(), add_bos=False)
        # SentencePiece adds a leading space (the "dummy prefix") when detokenizing.
        assert llm.detokenize(tokens).decode().removeprefix(" ") == text
        # Control tokens in a prompt are single tokens, not spelled out in bytes.
        assert len(llm.tokenize(b"<|im_start|>", add_bos=False, special=True)) == 1
    finally:
        llm.close()


def test_tiny_gguf_is_cached_and_seeded(tmp_path) -> None:
    path = str(tmp_path / "a.gguf")
    assert make_tiny_llama_gguf(path) == path
    mtime = os.stat(path).st_mtime_ns
    assert make_tiny_llama_gguf(path, seed=1) == path  # exists: returned untouched
    assert os.stat(path).st_mtime_ns == mtime
    other = make_tiny_llama_gguf(str(tmp_path / "b.gguf"), seed=1)
    same = make_tiny_llama_gguf(str(tmp_path / "c.gguf"), seed=0)
    with open(path, "rb") as a, open(other, "rb") as b, open(same, "rb") as c:
        data_a = a.read()
        assert data_a != b.read()
        assert data_a == c.read()
