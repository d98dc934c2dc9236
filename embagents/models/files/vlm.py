"""The two files of a vision-language model: the language model and its vision projector (mmproj).

A :class:`~embagents.models.VLMModel` names each as a local path or a Hugging
Face repo id (``owner/name:file-glob``); with neither, moondream2 (as
EmbodiedAgents). A projector left out is found next to a local model file
(``*mmproj*.gguf`` in its folder) or in the model's repo. No small VLM ships
on PyPI, so offline :func:`pair_problem` says which files are missing and how
to bring them.

Example::

    >>> model_specs(None, None)
    ('vikhyatk/moondream2:*text-model*.gguf', 'vikhyatk/moondream2:*mmproj*.gguf')
    >>> model_specs("someone/llava-gguf", None)
    ('someone/llava-gguf', 'someone/llava-gguf:*mmproj*.gguf')
"""

from __future__ import annotations

import glob
import os

from embagents.models.files.hub import (
    _cached_hub_file,
    _hub_unreachable_reason,
    _looks_like_path,
    local_file_problem,
    resolve_model_path,
)

__all__ = ["DEFAULT_VLM_REPO", "model_specs", "pair_problem", "resolve_pair"]

#: The default VLM, as EmbodiedAgents: moondream2's GGUF text model and projector.
DEFAULT_VLM_REPO = "vikhyatk/moondream2"
_PROJECTOR_GLOB = "*mmproj*.gguf"


def model_specs(model: str | None, projector: str | None) -> tuple[str, str]:
    """The (language model, projector) specs a VLMModel's two fields stand for."""
    if model is None:
        return f"{DEFAULT_VLM_REPO}:*text-model*.gguf", projector or f"{DEFAULT_VLM_REPO}:{_PROJECTOR_GLOB}"
    if projector is not None:
        return model, projector
    if _looks_like_path(model):
        folder = os.path.dirname(os.path.abspath(os.path.expanduser(model)))
        found = sorted(glob.glob(os.path.join(folder, _PROJECTOR_GLOB)))
        return model, found[0] if found else os.path.join(folder, _PROJECTOR_GLOB)
    return model, f"{model.partition(':')[0]}:{_PROJECTOR_GLOB}"


def resolve_pair(model: str, projector: str) -> tuple[str, str]:
    """Both files as local paths (downloaded once, with a progress bar, when they are repo ids)."""
    # A bare repo id takes LlamaModel's default quantisation (*Q4_K_M.gguf); `owner/name:glob` picks another.
    return resolve_model_path(model), resolve_model_path(projector, filename_glob=_PROJECTOR_GLOB)


def _repo_problem(spec: str) -> str | None:
    """Why a repo id cannot be had now (not cached, and no hub), found without downloading."""

    try:
        import huggingface_hub as hub
    except ImportError:
        return "huggingface_hub is not installed (pip install 'embagents[hub]')"
    repo, _, pattern = spec.partition(":")
    if _cached_hub_file(hub, repo, None, pattern or "*Q4_K_M.gguf"):  # resolve_model_path's default
        return None
    return _hub_unreachable_reason()


def pair_problem(name: str, model: str, projector: str) -> str | None:
    """Why model ``name``'s two files cannot be used, naming both and how to get them (None: fine).

    >>> print(pair_problem("eyes", "/no/llm.gguf", "/no/mmproj.gguf"))  # doctest: +ELLIPSIS
    a vision-language model needs two GGUF files, the language model and its vision projector (mmproj): ...
    """
    why: list[str] = []
    for what, spec in (("language model", model), ("projector", projector)):
        if _looks_like_path(spec):
            problem = local_file_problem(spec) if "*" not in spec else f"no {_PROJECTOR_GLOB} next to {model!r}"
            if problem:
                why.append(f"{what} {spec!r}: {problem.split('. ')[0]}")
        elif (problem := _repo_problem(spec)) is not None:
            why.append(f"{what} {spec!r}: not in the Hugging Face cache and the hub cannot be reached ({problem})")
    if not why:
        return None
    return ("a vision-language model needs two GGUF files, the language model and its vision projector (mmproj): "
            + "; ".join(why) + ". Get them where a hub is reachable, e.g. moondream2: `huggingface-cli download "
            f"{DEFAULT_VLM_REPO} --include '*text-model*' '{_PROJECTOR_GLOB}' --local-dir moondream2`, copy the "
            f"folder here and declare VLMModel(name={name!r}, local_model_path='moondream2/<...text-model...>.gguf', "
            "projector_path='moondream2/<...mmproj...>.gguf', chat_handler='moondream'); any LLaVA-style pair "
            "works with chat_handler='llava15'")
