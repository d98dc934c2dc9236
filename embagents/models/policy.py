"""Robot policies: observation in, a chunk of joint actions out.

Every policy a VLA drives is a :class:`PolicyClient`: ``infer(observation,
task, timeout_s)`` returns a float32 array of shape ``(actions_per_chunk,
n_joints)``. Observation keys follow LeRobot: ``"observation.state"``
(n_joints,) float32 and ``"observation.images.<camera>"`` (H, W, 3) uint8.
A LeRobot policy server is reached over gRPC by
:class:`~embagents.models.lerobot.LeRobotPolicyClient`.

(The same protocol as on the arm branch, whose file holds the ONNX policy too.)

Example::

    >>> image_key("front")
    'observation.images.front'
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol, runtime_checkable

import numpy as np

from embagents.models.protocol import ModelUnavailable

__all__ = ["STATE_KEY", "PolicyClient", "PolicyLate", "image_key"]

#: The observation key of the joint state vector (LeRobot's name).
STATE_KEY = "observation.state"


def image_key(camera: str) -> str:
    """The observation key of camera ``camera``'s image (LeRobot's naming).

    >>> image_key("front")
    'observation.images.front'
    """
    return f"observation.images.{camera}"


class PolicyLate(ModelUnavailable):
    """The policy gave no answer within the time the control loop allows."""


@runtime_checkable
class PolicyClient(Protocol):
    """What a VLA needs of a policy, wherever it runs."""

    def infer(self, observation: Mapping[str, np.ndarray], task: str, timeout_s: float) -> np.ndarray:
        """A chunk of actions, float32, shape (actions_per_chunk, n_joints); raises on timeout."""
        ...

    def close(self) -> None:
        """Let go of connections."""
        ...
