"""A tiny random-weight llama GGUF (~0.5 MB) for tests: every llama.cpp code path runs for real.

Its output is gibberish, but it loads in milliseconds, so backend tests load
and run a real model file without a model hub (the ``tiny_gguf`` fixture of
``tests/embagents/conftest.py``). Needs the ``gguf`` package (tests extra).
"""

from __future__ import annotations

import os

__all__ = ["TINY_CHAT_TEMPLATE", "make_tiny_llama_gguf"]

TINY_CHAT_TEMPLATE = (
    "{{ bos_token }}"
    "{% for message in messages %}"
    "<|im_start|>{{ message['role'] }}\n{{ message['content'] }}<|im_end|>\n"
    "{% endfor %}"
    "{% if add_generation_prompt %}<|im_start|>assistant\n{% endif %}"
)

_TINY_WORDS = (
    "the robot sees a red cup on table move left right stop go yes no hello "
    "world arm hand camera door open close map"
).split()


def make_tiny_llama_gguf(path: str, *, seed: int = 0) -> str:
    """Write a ~0.5 MB random-weight llama GGUF that llama-cpp-python loads in ~10 ms.

    2 layers, n_embd 64, a ~340-token SentencePiece-style vocab (control
    tokens, the 256 byte tokens, letters, digits, a few words) and a ChatML
    chat template in ``tokenizer.chat_template`` (end of turn: ``<|im_end|>``).
    Output is gibberish, but load, chat, streaming and stop strings all run
    for real. Cached: an existing file at ``path`` is returned as is.

    Example::

        >>> import tempfile
        >>> p = make_tiny_llama_gguf(os.path.join(tempfile.mkdtemp(), "tiny-llama.gguf"))
        >>> os.path.getsize(p) < 1_000_000
        True
    """
    if os.path.isfile(path):
        return path
    import gguf
    import numpy as np

    rng = np.random.default_rng(seed)
    n_embd, n_ff, n_layer, n_head = 64, 128, 2, 4

    tokens: list[str] = ["<unk>", "<s>", "</s>", "<|im_start|>", "<|im_end|>"]
    types: list[int] = [gguf.TokenType.UNKNOWN] + [gguf.TokenType.CONTROL] * 4
    # Byte fallback tokens: any text can be tokenized (llama.cpp's SPM needs them).
    tokens += [f"<0x{b:02X}>" for b in range(256)]
    types += [gguf.TokenType.BYTE] * 256
    pieces = ["\u2581"] + list(
        "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789.,!?'"
    )
    pieces += ["\u2581" + w for w in _TINY_WORDS]
    n_special = len(tokens)
    tokens += pieces
    types += [gguf.TokenType.NORMAL] * len(pieces)
    # SPM merges prefer higher scores: longer pieces first.
    scores = [0.0] * n_special + [float(len(p)) - 10.0 for p in pieces]
    n_vocab = len(tokens)

    def w(*shape: int, scale: float | None = None) -> np.ndarray:
        std = scale if scale is not None else 1.0 / np.sqrt(shape[-1])
        return (rng.standard_normal(shape) * std).astype(np.float32)

    output = w(n_vocab, n_embd, scale=0.5)
    # Zero logits for control/byte tokens: greedy decoding then emits readable
    # pieces (no half UTF-8 sequences, no early end-of-turn) in tests.
    output[:n_special] = 0.0

    tmp = f"{path}.{os.getpid()}.tmp"
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    writer = gguf.GGUFWriter(tmp, "llama")
    writer.add_name("embagents-tiny-llama")
    writer.add_context_length(2048)
    writer.add_embedding_length(n_embd)
    writer.add_block_count(n_layer)
    writer.add_feed_forward_length(n_ff)
    writer.add_head_count(n_head)
    writer.add_head_count_kv(n_head)
    writer.add_rope_dimension_count(n_embd // n_head)
    writer.add_layer_norm_rms_eps(1e-5)
    writer.add_file_type(gguf.LlamaFileType.ALL_F32)
    writer.add_tokenizer_model("llama")
    writer.add_token_list(tokens)
    writer.add_token_scores(scores)
    writer.add_token_types(types)
    writer.add_unk_token_id(0)
    writer.add_bos_token_id(1)
    writer.add_eos_token_id(4)  # <|im_end|>: the end of an assistant turn
    writer.add_add_bos_token(False)  # the template writes bos_token itself
    writer.add_chat_template(TINY_CHAT_TEMPLATE)

    # numpy shape is (rows, cols) = (out, in); gguf stores it reversed, as llama.cpp expects.
    writer.add_tensor("token_embd.weight", w(n_vocab, n_embd, scale=1.0))
    writer.add_tensor("output_norm.weight", np.ones(n_embd, dtype=np.float32))
    writer.add_tensor("output.weight", output)
    for i in range(n_layer):
        writer.add_tensor(f"blk.{i}.attn_norm.weight", np.ones(n_embd, dtype=np.float32))
        for name in ("attn_q", "attn_k", "attn_v", "attn_output"):
            writer.add_tensor(f"blk.{i}.{name}.weight", w(n_embd, n_embd))
        writer.add_tensor(f"blk.{i}.ffn_norm.weight", np.ones(n_embd, dtype=np.float32))
        writer.add_tensor(f"blk.{i}.ffn_gate.weight", w(n_ff, n_embd))
        writer.add_tensor(f"blk.{i}.ffn_up.weight", w(n_ff, n_embd))
        writer.add_tensor(f"blk.{i}.ffn_down.weight", w(n_embd, n_ff))
    try:
        writer.write_header_to_file()
        writer.write_kv_data_to_file()
        writer.write_tensors_to_file()
    finally:
        writer.close()
    # Atomic publish: concurrent test workers never see a half-written file.
    os.replace(tmp, path)
    return path
