"""The VLM component against a real VLM model actor (the tiny generated LLaVA-style model)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

pytest.importorskip("llama_cpp")
pytest.importorskip("cv2")

from actors import ActorSystem  # noqa: E402
from embagents.components import MLLM, VLM, HealthStatus, VLMConfig  # noqa: E402
from embagents.components.grounding import parse_boxes  # noqa: E402
from embagents.models import LocalModelClient, VLMModel  # noqa: E402
from embagents.models.actor import ModelActor  # noqa: E402
from embagents.msgs import CompressedImage, Detections, Image, StreamingString, String  # noqa: E402
from embagents.topic import Topic  # noqa: E402

question, camera, answer = Topic("question", String), Topic("camera", Image), Topic("answer", String)
FRAME = Image(data=np.full((240, 320, 3), 90, np.uint8), frame_id="cam", stamp=3.0)


@pytest.fixture(scope="module")
def eyes(tiny_vlm: tuple[str, str]) -> Iterator[LocalModelClient]:
    model = VLMModel(name="eyes", local_model_path=tiny_vlm[0], chat_handler="llava15", n_ctx=512)
    with ActorSystem() as asys:
        asys.spawn(ModelActor, "eyes", "vlm", model.resolve(), model.options(), True, wait=60)
        yield LocalModelClient(model, timeout=60)


def vlm(client: Any, outputs: Any = (answer,), **config: Any) -> tuple[VLM, list[Any]]:
    comp = VLM(name="vlm", inputs=[question, camera], outputs=list(outputs), model_client=client,
               config=VLMConfig(max_new_tokens=6, temperature=0.0, **config))
    sent: list[Any] = []
    comp.attach(lambda topic, msg: sent.append((topic, msg)))
    return comp, sent


def step(comp: VLM, topic: str, msg: Any) -> bool:
    return comp.on_message(topic, msg) and comp.execute()


def test_a_question_is_answered_about_the_latest_frame(eyes: LocalModelClient) -> None:
    comp, sent = vlm(eyes, outputs=[answer, Topic("tokens", StreamingString)], stream=True, chat_history=True)
    step(comp, "camera", FRAME)
    assert sent == []  # a frame alone asks nothing
    assert step(comp, "question", String("what is on the table?"))
    text = sent[-1][1].data
    tokens = [m for t, m in sent if t == "tokens"]
    assert len(text) > 0 and "".join(m.data for m in tokens) == text and tokens[-1].done
    assert comp.history == [{"role": "user", "content": "what is on the table?"},
                            {"role": "assistant", "content": text}]  # text only: frames are not kept


def test_a_question_before_any_frame_is_a_clear_error_and_is_answered_when_the_frame_comes(eyes: LocalModelClient) -> None:
    comp, sent = vlm(eyes)
    assert not step(comp, "question", String("what do you see?"))
    assert comp.health.status == HealthStatus.ALGORITHM_FAILURE
    assert "no image has arrived yet on camera; is the camera publishing?" in comp.health.text
    assert "answered when the first frame comes" in comp.health.text and sent == []
    assert step(comp, "camera", FRAME)
    assert comp.health.status == HealthStatus.HEALTHY and len(sent) == 1 and sent[0][0] == "answer"


def test_an_image_of_the_wrong_shape_is_named_and_a_good_one_answers_the_question(eyes: LocalModelClient) -> None:
    comp, sent = vlm(eyes)
    step(comp, "camera", Image(data=np.zeros((240, 320), np.uint8), encoding="rgb8"))
    assert not step(comp, "question", String("what?"))
    assert "frame on 'camera': Image of encoding 'rgb8' and shape (240, 320) is not one this reads" in comp.health.text
    assert sent == []
    assert step(comp, "camera", FRAME) and len(sent) == 1  # the question waited for a good frame


def test_describe_answers_about_a_topic_and_names_bad_topics(eyes: LocalModelClient) -> None:
    comp, sent = vlm(eyes)
    with pytest.raises(RuntimeError, match=r"no image on 'camera' yet"):
        comp.describe("camera", "what is there?")
    with pytest.raises(ValueError, match=r"describe needs one of its image inputs \(camera\), not 'question'"):
        comp.describe("question")
    comp.on_message("camera", FRAME)
    text = comp.describe("camera", "what is there?")
    assert text and sent == [("answer", String(data=text))]


def test_a_compressed_frame_is_decoded_for_the_model(eyes: LocalModelClient) -> None:
    import cv2

    jpeg = Topic("jpeg", CompressedImage)
    comp = VLM(name="vlm", inputs=[question, jpeg], outputs=[answer], model_client=eyes,
               config=VLMConfig(max_new_tokens=3))
    sent: list[Any] = []
    comp.attach(lambda topic, msg: sent.append(msg))
    ok, data = cv2.imencode(".jpg", np.zeros((32, 32, 3), np.uint8))
    comp.on_message("jpeg", CompressedImage(data=data.tobytes(), format="jpeg"))
    assert step(comp, "question", String("what?")) and len(sent) == 1  # type: ignore[arg-type]


class Grounder:
    """A chat client answering as Qwen2.5-VL does to a grounding request (the parsing path, no model)."""

    name = "grounder"

    def chat_stream(self, messages: list[dict], images: Any = (), **options: Any) -> Iterator[dict]:
        h, w = images[0].shape[:2]
        yield {"delta": f'```json\n[{{"bbox_2d": [10, 20, {w // 2}, {h // 2}], "label": "cup"}}]\n```'}
        yield {"done": True, "finish_reason": "stop", "tool_calls": None}


def test_boxes_in_an_answer_are_published_as_detections_of_the_frame() -> None:
    comp, sent = vlm(Grounder(), outputs=[answer, Topic("found", Detections)])
    comp.on_message("camera", FRAME)
    assert step(comp, "question", String("where is the cup? answer with a bounding box"))
    (det,) = [m for t, m in sent if t == "found"]
    assert det.labels == ["cup"] and det.boxes.tolist() == [[10.0, 20.0, 160.0, 120.0]]
    assert (det.image_width, det.image_height, det.frame_id, det.stamp) == (320, 240, "cam", 3.0)


def test_a_vlm_needs_an_image_input_and_mllm_is_the_same_component() -> None:
    from embagents.components import ComponentError

    assert MLLM is VLM
    with pytest.raises(ComponentError, match="needs an input topic of type Image or CompressedImage"):
        VLM(name="vlm", inputs=[question], outputs=[answer], model_client=Grounder())
    from embagents.models import LlamaModel

    with pytest.raises(ComponentError, match="serves a 'llama' model, which takes no images; give it LocalModelClient"):
        VLM(name="vlm", inputs=[question, camera], outputs=[answer],
            model_client=LocalModelClient(LlamaModel(name="talk")))


@pytest.mark.parametrize(("text", "boxes", "labels"), [
    # Qwen2.5-VL (pixels, JSON in a fence)
    ('```json\n[\n\t{"bbox_2d": [135, 114, 1016, 672], "label": "dog"}\n]\n```', [[135, 114, 640, 480]], ["dog"]),
    # Qwen2-VL (0..1000)
    ("<|object_ref_start|>the red cup<|object_ref_end|><|box_start|>(100,250),(500,750)<|box_end|>",
     [[64, 120, 320, 360]], ["the red cup"]),
    # PaliGemma (y1 x1 y2 x2, 0..1023 bins over 1024)
    ("<loc0256><loc0128><loc0768><loc0512> cat ; <loc0000><loc0000><loc0512><loc0512> dog",
     [[80, 120, 320, 360], [0, 0, 320, 240]], ["cat", "dog"]),
    # Florence-2 (x1 y1 x2 y2, 0..999 bins over 1000)
    ("car<loc_0><loc_500><loc_250><loc_1000>", [[0, 240, 160, 480]], ["car"]),
    # LLaVA / moondream: a normalised list after its label
    ("red cup: [0.25, 0.5, 0.75, 1.0]", [[160, 240, 480, 480]], ["red cup"]),
    ("The cup is at [0.25, 0.5, 0.75, 1.0].", [[160, 240, 480, 480]], ["cup"]),
    ("[120, 40, 300, 200]", [[120, 40, 300, 200]], ["object"]),
    ("I see three cups and a plate.", [], []),
])
def test_box_formats_of_real_vlms_are_read_in_pixels(text: str, boxes: list, labels: list) -> None:
    got, names = parse_boxes(text, 640, 480)
    assert np.allclose(got, np.array(boxes, np.float32).reshape(-1, 4)) and names == labels


class Recorder:
    """A chat client that keeps what it was sent (what the LLM's history and templates build, with the frames)."""

    name = "recorder"

    def __init__(self) -> None:
        self.sent: list[tuple[list[dict], list]] = []

    def chat_stream(self, messages: list[dict], images: Any = (), **options: Any) -> Iterator[dict]:
        self.sent.append((messages, list(images)))
        yield {"delta": f"answer {len(self.sent)}"}
        yield {"done": True, "finish_reason": "stop", "tool_calls": None}


def test_history_system_prompt_and_template_are_the_llms_and_frames_go_with_the_last_question() -> None:
    rec = Recorder()
    comp, _ = vlm(rec, chat_history=True, system_prompt="You see through the robot's camera.",
                  prompt_template="Look closely. {text}")
    comp.on_message("camera", FRAME)
    step(comp, "question", String("what is it?"))
    step(comp, "camera", Image(data=np.zeros((10, 20, 3), np.uint8)))
    step(comp, "question", String("and now?"))
    messages, images = rec.sent[-1]
    assert messages == [{"role": "system", "content": "You see through the robot's camera."},
                        {"role": "user", "content": "Look closely. what is it?"},
                        {"role": "assistant", "content": "answer 1"},
                        {"role": "user", "content": "Look closely. and now?"}]
    assert [i.shape for i in images] == [(10, 20, 3)]  # the latest frame only, once
    assert comp.snapshot()["history"][-1] == {"role": "assistant", "content": "answer 2"}
