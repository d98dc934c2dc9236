"""The VLM component (alias ``MLLM``, as EmbodiedAgents names it): text and images in, text out.

A question on a ``String`` input is answered about the latest frame of every
``Image`` / ``CompressedImage`` input, through a vision-language model client:
a :class:`~embagents.models.VLMModel` behind a
:class:`~embagents.models.LocalModelClient` (frames cross through shared
memory) or :class:`~embagents.models.clients.openai_http.OpenAIHTTPClient` on a server
that takes images. Everything the :class:`~embagents.components.llm.LLM` does
carries over: chat history (text only: past frames are not sent again),
system prompt and prompt templates, streaming to a ``StreamingString`` output,
``snapshot()`` / ``restore()``. With a ``Detections`` output, an answer that
holds boxes (a grounding request: "where is the cup? answer with a bounding
box") is published as detections too (:mod:`embagents.components.grounding`).

A question that arrives before any frame is not lost: the component reports
an algorithm failure naming the image topics and answers the question when
the first frame comes. The action ``describe(topic, query)`` answers about
the latest frame of one topic (from events: ``call(vlm, "describe", "camera",
"what do you see?")``, or from the CLI).

Example::

    >>> from embagents.msgs import Image, String
    >>> from embagents.topic import Topic
    >>> class Looker:
    ...     def chat_stream(self, messages, images=(), **options):
    ...         yield {"delta": f"{len(images)} image(s) of {images[0].shape[1]}x{images[0].shape[0]}"}
    ...         yield {"done": True, "finish_reason": "stop", "tool_calls": None}
    >>> vlm = VLM(name="vlm", inputs=[Topic("question", String), Topic("camera", Image)],
    ...           outputs=[Topic("answer", String)], model_client=Looker())
    >>> sent = []
    >>> vlm.attach(lambda topic, msg: sent.append(msg))
    >>> vlm.on_message("camera", Image(data=np.zeros((48, 64, 3), np.uint8)))
    True
    >>> vlm.on_message("question", String("what is there?")) and vlm.execute()
    True
    >>> sent
    [String(data='1 image(s) of 64x48')]
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from attrs import define, field

from embagents.components.component import ComponentProblem
from embagents.components.grounding import parse_boxes
from embagents.components.imaging import image_rgb
from embagents.components.llm import LLM, LLMConfig
from embagents.msgs import CompressedImage, Detections, Image, StreamingString, String
from embagents.topic import Topic

__all__ = ["MLLM", "VLM", "NoImageYet", "VLMConfig"]

_IMAGES = (Image, CompressedImage)


class NoImageYet(RuntimeError):
    """A question came before any frame on the VLM's image inputs."""


def _label(value: object) -> str:
    if not isinstance(value, str) or not value:
        raise ValueError(f"detection_label must be a non-empty string, got {value!r}")
    return value


@define(kw_only=True)
class VLMConfig(LLMConfig):
    """Settings of :class:`VLM`: those of :class:`~embagents.components.llm.LLMConfig`, and

    - ``detection_label``: the label of a box the model's answer gives without one.

    >>> VLMConfig(max_new_tokens="64").max_new_tokens
    64
    """

    detection_label: str = field(default="object", converter=_label)


class VLM(LLM):
    """Answers questions about what the cameras see (see the module docstring)."""

    allowed_inputs = {"Required": [String], "Optional": [String, Image, CompressedImage]}
    allowed_outputs = {"Required": [[String, StreamingString]], "Optional": [String, StreamingString, Detections]}
    config_class = VLMConfig

    def __init__(self, *, name: str, **kw: Any) -> None:
        self._images: list[np.ndarray] = []
        self._pending: tuple[str, dict[str, str]] | None = None
        super().__init__(name=name, **kw)

    @property
    def image_topics(self) -> list[Topic]:
        """The input topics that carry frames."""
        return [t for t in self.inputs if issubclass(t.msg_type, _IMAGES)]

    def default_trigger(self) -> list[Topic] | None:
        # Frames trigger too: a question that came before the first frame is answered when it comes.
        return list(self.inputs) or None

    def validate(self) -> list[ComponentProblem]:
        problems = super().validate()
        if not self.image_topics:
            problems.append(("missing-input", f"{self._label()}: needs an input topic of type Image or "
                                              "CompressedImage (the camera it answers about)"))
        for key, client in self.clients.items():
            kind = getattr(getattr(client, "model", None), "kind", "vlm")
            if kind != "vlm":
                problems.append(("bad-client", f"{self._label()}: model client {key!r} serves a {kind!r} model, which "
                                               "takes no images; give it LocalModelClient(VLMModel(...))"))
        return problems

    def run_warmup(self) -> None:
        for _ in self.chat_stream([{"role": "user", "content": "Hi"}], max_tokens=1,
                                  images=[np.zeros((8, 8, 3), np.uint8)]):
            pass

    # --- steps ------------------------------------------------------------------------------
    def _execution_step(self, **inputs: Any) -> None:
        texts = [t for t in self.inputs if t.msg_type is String]
        question = next((t for t in texts if t.name in self.fresh_inputs and inputs.get(t.name) is not None), None)
        if question is not None:
            context = {t.name.replace("/", "_"): inputs[t.name].data for t in texts
                       if t is not question and inputs.get(t.name) is not None}
            self._pending = (self.question_text(question, inputs), context)
        if self._pending is None:
            return  # a frame, and no question waiting
        frames = [(t.name, inputs[t.name]) for t in self.image_topics if inputs.get(t.name) is not None]
        if not frames:
            raise NoImageYet(
                f"{self._label()}: asked {self._pending[0]!r} but no image has arrived yet on "
                f"{', '.join(t.name for t in self.image_topics)}; is the camera publishing? (`embagents status`). "
                "The question is answered when the first frame comes")
        images = [self._rgb(name, msg) for name, msg in frames]  # a bad frame keeps the question for the next
        text, context = self._pending
        self._pending = None
        self._answer_about(text, images, frames[0][1], context)

    def _rgb(self, topic: str, frame: Any) -> np.ndarray:
        try:
            return image_rgb(frame)
        except ValueError as exc:
            raise ValueError(f"{self._label()}: frame on {topic!r}: {exc}") from None

    def ask(self, text: str, frames: list[Image | CompressedImage], context: Mapping[str, str] | None = None) -> str:
        """Answer ``text`` about ``frames``: publish the answer (and boxes as Detections); returns it.

        Raises ``ValueError`` naming the problem for a frame of the wrong shape or type.
        """
        images = [self._rgb("ask", f) for f in frames]
        return self._answer_about(text, images, frames[0], context)

    def _answer_about(self, text: str, images: list[np.ndarray], first: Image | CompressedImage,
                      context: Mapping[str, str] | None) -> str:
        self._images = images
        try:
            answer = self.answer(text, context)
        finally:
            self._images = []
        self._publish_boxes(answer, images[0], first)
        return answer

    def _model_inputs(self) -> dict[str, Any]:
        return {"images": self._images} if self._images else {}

    def _publish_boxes(self, answer: str, image: np.ndarray, frame: Image | CompressedImage) -> None:
        outs = [t for t in self.outputs if t.msg_type is Detections]
        if not outs:
            return
        h, w = image.shape[:2]
        boxes, labels = parse_boxes(answer, w, h, default_label=self.config.detection_label)
        if not len(boxes):
            return
        det = Detections(boxes=boxes, labels=labels, scores=np.ones(len(labels), np.float32), image_width=w,
                         image_height=h, stamp=frame.stamp, frame_id=frame.frame_id)
        for t in outs:
            self.publish(t, det)

    # --- actions ----------------------------------------------------------------------------
    def describe(self, topic: str, query: str = "Describe what you see.") -> str:
        """Answer ``query`` about the latest frame of input ``topic``; returns (and publishes) the answer.

        Raises ``ValueError`` for a topic that is not an image input, :class:`NoImageYet`
        when no (recent enough) frame has come on it.
        """
        names = [t.name for t in self.image_topics]
        if topic not in names:
            raise ValueError(f"{self._label()}: describe needs one of its image inputs ({', '.join(names) or 'none'}), "
                             f"not {topic!r}")
        frame = self.current_inputs().get(topic)
        if frame is None:
            raise NoImageYet(f"{self._label()}: no image on {topic!r} yet (or none newer than input_max_age_s); "
                             "is the camera publishing? (`embagents status`)")
        return self._answer_about(query, [self._rgb(topic, frame)], frame, None)


#: EmbodiedAgents' name for the same component.
MLLM = VLM
