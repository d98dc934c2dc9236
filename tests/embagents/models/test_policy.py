"""ONNX policies served by a real model actor on onnxruntime (LocalPolicyClient, PolicyServing)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

from actors import ActorSystem  # noqa: E402
from embagents.models import BadRequest, LocalPolicyClient, PolicyClient, PolicyLate, PolicyModel  # noqa: E402
from embagents.models.actor import ModelActor  # noqa: E402
from embagents.models.backends.reach_policy import write_reach_policy  # noqa: E402
from tests.embagents.conftest import PANDA_TARGET  # noqa: E402


@pytest.fixture(scope="module")
def served(reach_policy: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, str]]:
    seeing = write_reach_policy(str(tmp_path_factory.mktemp("p") / "seeing.onnx"), [1.0, 2.0], gain=1.0, chunk=2,
                                camera="front", image_size=(24, 32))
    with ActorSystem() as asys:
        asys.spawn(ModelActor, "reach", "policy", reach_policy, {"threads": 1}, True, wait=60)
        asys.spawn(ModelActor, "seeing", "policy", seeing, {"threads": 1}, True, wait=60)
        yield {"reach": "reach", "seeing": "seeing"}


def test_a_state_gives_a_chunk_of_actions_toward_the_target(served: dict[str, str]) -> None:
    policy = LocalPolicyClient(PolicyModel(name="reach", local_model_path="unused.onnx"))
    assert isinstance(policy, PolicyClient)
    q = np.zeros(7, np.float32)
    chunk = policy.infer({"observation.state": q}, "reach", timeout_s=10.0)
    assert chunk.shape == (10, 7) and chunk.dtype == np.float32
    assert np.allclose(chunk[0], 0.2 * np.array(PANDA_TARGET), atol=1e-6)  # gain 0.2 of the error, once
    assert np.abs(chunk[-1] - PANDA_TARGET).max() < np.abs(chunk[0] - PANDA_TARGET).max()  # closer at each step
    policy.close()


def test_an_image_goes_to_the_policy_and_a_wrong_one_is_refused_naming_both_shapes(served: dict[str, str]) -> None:
    policy = LocalPolicyClient("seeing")
    image = np.full((24, 32, 3), 255, np.uint8)
    assert policy.infer({"observation.state": np.zeros(2, np.float32), "observation.images.front": image},
                        "look", 10.0).tolist() == [[1.0, 2.0], [1.0, 2.0]]
    with pytest.raises(BadRequest, match=r"'observation.images.front' has shape \(48, 64, 3\); the policy expects "
                                         r"\(24, 32, 3\)"):
        policy.infer({"observation.state": np.zeros(2, np.float32), "observation.images.front": np.zeros((48, 64, 3), np.uint8)},
                     "look", 10.0)
    with pytest.raises(BadRequest, match=r"observation lacks 'observation.images.front'"):
        policy.infer({"observation.state": np.zeros(2, np.float32)}, "look", 10.0)


def test_a_policy_that_cannot_answer_in_time_is_late_and_the_next_ask_works(served: dict[str, str]) -> None:
    policy = LocalPolicyClient("reach")
    with pytest.raises(PolicyLate, match="gave no actions within"):
        policy.infer({"observation.state": np.zeros(7, np.float32)}, "reach", timeout_s=1e-6)
    assert policy.infer({"observation.state": np.zeros(7, np.float32)}, "reach", 10.0).shape == (10, 7)


def test_a_policy_model_without_a_file_says_what_it_needs() -> None:
    assert "needs local_model_path" in (PolicyModel(name="p").file_problem() or "")


def test_a_missing_policy_file_says_how_to_get_one() -> None:
    problem = PolicyModel(name="p", local_model_path="/nowhere/p.onnx").file_problem() or ""
    assert "ONNX file '/nowhere/p.onnx' not found" in problem and "write_reach_policy" in problem
