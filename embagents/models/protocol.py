"""The inference protocol: one request / answer shape for every modality.

A client sends an :class:`InferRequest` (a task name, ``inputs`` that may hold
numpy arrays, ``options``) to a model actor's socket at ``<run>/<name>.inf``;
the actor answers with :class:`InferAnswer` frames (one with ``done=True`` for
a single answer such as detections, or a stream of chunks ending with a
``done`` one, such as tokens) or one :class:`InferError`. A client that gives
up sends :class:`InferCancel`. Frames go through the actors codec: arrays of
64 KB and more travel through shared memory (a 1080p frame is written once
into a segment, the socket carries its handle), nothing is pickled.

Example::

    >>> from actors.codec import Codec
    >>> req = InferRequest(id=1, task="detect", inputs={"image": "..."})
    >>> Codec().decode(Codec().encode(req)[0]).task
    'detect'
"""

from __future__ import annotations

from typing import Any

import attrs

from actors.codec import message

__all__ = [
    "BadRequest",
    "InferAnswer",
    "InferCancel",
    "InferError",
    "InferRequest",
    "ModelCrashed",
    "ModelError",
    "ModelUnavailable",
    "StaleInput",
    "inference_endpoint",
]


class ModelUnavailable(RuntimeError):
    """The model actor did not answer (not running, crashed, or too slow)."""


class ModelCrashed(ModelUnavailable):
    """The model actor died while requests were waiting; each of them fails at once."""


class ModelError(RuntimeError):
    """The model actor answered the request with an error (``kind`` says which)."""

    def __init__(self, text: str, kind: str = "failed") -> None:
        super().__init__(text)
        self.kind = kind


class BadRequest(ModelError, ValueError):
    """A request the model cannot run (wrong task, input shape, dtype or option); answered at once."""

    def __init__(self, text: str) -> None:
        super().__init__(text, "bad_request")


class StaleInput(ModelError):
    """A camera frame the request forwarded was overwritten by its publisher before the model was done
    with it (its topic ring came round): the answer is dropped, as the frame would have been. Take the next."""

    def __init__(self, text: str) -> None:
        super().__init__(text, "stale")


@message("embagents/InferRequest")
@attrs.define
class InferRequest:
    """Run ``task`` on ``inputs`` (arrays, text, chat messages) with ``options``."""

    id: int = 0
    task: str = ""
    inputs: dict[str, Any] = attrs.field(factory=dict)
    options: dict[str, Any] = attrs.field(factory=dict)


@message("embagents/InferAnswer")
@attrs.define
class InferAnswer:
    """One answer, or one chunk of a streamed answer; ``done`` marks the last."""

    id: int = 0
    outputs: dict[str, Any] = attrs.field(factory=dict)
    done: bool = True


@message("embagents/InferError")
@attrs.define
class InferError:
    """Request ``id`` failed: ``kind`` is bad_request, failed, cancelled or stale; ``error`` says why."""

    id: int = 0
    error: str = ""
    kind: str = "failed"


@message("embagents/InferCancel")
@attrs.define
class InferCancel:
    """The client gave up on request ``id``: drop it if queued, stop it if running."""

    id: int = 0


def inference_endpoint(run_dir: str, model: str) -> str:
    """The ZeroMQ endpoint of model actor ``model``'s inference socket.

    >>> inference_endpoint("/run/x", "yolo")
    'ipc:///run/x/yolo.inf'
    """
    return f"ipc://{run_dir}/{model}.inf"
