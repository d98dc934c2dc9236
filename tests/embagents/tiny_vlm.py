"""A tiny random LLaVA-style vision projector (mmproj GGUF, ~140 KB) for tests.

Next to the tiny llama of ``tiny_llama.py`` it makes a vision-language model
that llama-cpp-python's ``Llava15ChatHandler`` loads: a one-block CLIP-style
ViT (28x28 images, 14-pixel patches) and the LLaVA-1.5 ``mlp`` projector
into the tiny llama's 64-wide embeddings. Output is gibberish, but image
decoding, encoding, projection and generation all run for real (the
``tiny_vlm`` fixture of ``tests/embagents/conftest.py``). Needs ``gguf``.
"""

from __future__ import annotations

import os

__all__ = ["make_tiny_mmproj_gguf"]


def make_tiny_mmproj_gguf(path: str, *, n_embd_text: int = 64, seed: int = 0) -> str:
    """Write a random LLaVA-1.5 style mmproj GGUF projecting to ``n_embd_text``; cached at ``path``.

    Example::

        >>> import tempfile
        >>> p = make_tiny_mmproj_gguf(os.path.join(tempfile.mkdtemp(), "tiny-mmproj.gguf"))
        >>> os.path.getsize(p) < 200_000
        True
    """
    if os.path.isfile(path):
        return path
    import gguf
    import numpy as np

    rng = np.random.default_rng(seed)
    n_embd, n_ff, n_layer, n_head, image, patch = 32, 64, 1, 4, 28, 14

    def w(*shape: int) -> np.ndarray:
        return (rng.standard_normal(shape) / np.sqrt(shape[-1])).astype(np.float32)

    def ones(n: int) -> np.ndarray:
        return np.ones(n, np.float32)

    def zeros(n: int) -> np.ndarray:
        return np.zeros(n, np.float32)

    tmp = f"{path}.{os.getpid()}.tmp"
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    writer = gguf.GGUFWriter(tmp, "clip")
    writer.add_clip_has_vision_encoder(True)
    writer.add_clip_projector_type("mlp")  # LLaVA-1.5: mm.0 -> GELU -> mm.2
    writer.add_vision_image_size(image)
    writer.add_vision_patch_size(patch)
    writer.add_vision_embedding_length(n_embd)
    writer.add_vision_feed_forward_length(n_ff)
    writer.add_vision_projection_dim(n_embd_text)
    writer.add_vision_block_count(n_layer)
    writer.add_vision_head_count(n_head)
    writer.add_vision_attention_layernorm_eps(1e-5)
    writer.add_vision_image_mean([0.5, 0.5, 0.5])
    writer.add_vision_image_std([0.5, 0.5, 0.5])
    writer.add_vision_use_gelu(True)
    writer.add_file_type(gguf.LlamaFileType.ALL_F32)
    writer.add_tensor("v.patch_embd.weight", w(n_embd, 3, patch, patch))
    writer.add_tensor("v.class_embd", w(n_embd))
    writer.add_tensor("v.position_embd.weight", w((image // patch) ** 2 + 1, n_embd))
    writer.add_tensor("v.pre_ln.weight", ones(n_embd))
    writer.add_tensor("v.pre_ln.bias", zeros(n_embd))
    for i in range(n_layer):
        for name in ("attn_q", "attn_k", "attn_v", "attn_out"):
            writer.add_tensor(f"v.blk.{i}.{name}.weight", w(n_embd, n_embd))
            writer.add_tensor(f"v.blk.{i}.{name}.bias", zeros(n_embd))
        for name in ("ln1", "ln2"):
            writer.add_tensor(f"v.blk.{i}.{name}.weight", ones(n_embd))
            writer.add_tensor(f"v.blk.{i}.{name}.bias", zeros(n_embd))
        writer.add_tensor(f"v.blk.{i}.ffn_up.weight", w(n_ff, n_embd))
        writer.add_tensor(f"v.blk.{i}.ffn_up.bias", zeros(n_ff))
        writer.add_tensor(f"v.blk.{i}.ffn_down.weight", w(n_embd, n_ff))
        writer.add_tensor(f"v.blk.{i}.ffn_down.bias", zeros(n_embd))
    writer.add_tensor("mm.0.weight", w(n_embd_text, n_embd))
    writer.add_tensor("mm.0.bias", zeros(n_embd_text))
    writer.add_tensor("mm.2.weight", w(n_embd_text, n_embd_text))
    writer.add_tensor("mm.2.bias", zeros(n_embd_text))
    try:
        writer.write_header_to_file()
        writer.write_kv_data_to_file()
        writer.write_tensors_to_file()
    finally:
        writer.close()
    os.replace(tmp, path)  # atomic: concurrent test workers never see a half-written file
    return path
