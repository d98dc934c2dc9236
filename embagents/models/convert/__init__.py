"""Converters that turn a published model into the file a backend runs: each once, cached.

:mod:`~embagents.models.convert.whisper` (Whisper to sherpa-onnx ONNX), :mod:`~embagents.models.convert.piper`
(a Piper voice for sherpa-onnx), :mod:`~embagents.models.convert.bert` (a BERT encoder to ONNX).
"""
