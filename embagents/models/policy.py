"""Robot policies: observation in, a chunk of joint actions out.

Every policy a :class:`~embagents.components.VLA` drives is a
:class:`PolicyClient`: ``infer(observation, task, timeout_s)`` returns a
float32 array of shape ``(actions_per_chunk, n_joints)``. Observation keys
follow LeRobot: ``"observation.state"`` (n_joints,) float32 and
``"observation.images.<camera>"`` (H, W, 3) uint8. Two kinds exist:

- :class:`LocalPolicyClient`: an ONNX policy file (:class:`PolicyModel`)
  served by a model actor on onnxruntime (task ``"act"``: each model input
  is named by an observation key, a batch dimension of 1 is added; the
  first output is the chunk, ``(1, T, N)`` or ``(T, N)``);
- a LeRobot policy server over gRPC (:class:`~embagents.models.lerobot.LeRobotPolicyClient`).

Example::

    >>> policy = LocalPolicyClient(PolicyModel(name="reach", local_model_path="reach.onnx"))
    >>> policy.name
    'reach'
    >>> isinstance(policy, PolicyClient)
    True
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any, ClassVar, Protocol, runtime_checkable

import attrs
import numpy as np

from embagents.models.backends.onnx import OnnxSession
from embagents.models.client import LocalModelClient
from embagents.models.declarations import Model
from embagents.models.protocol import BadRequest, ModelUnavailable
from embagents.realtime import raise_priority

__all__ = ["PolicyClient", "PolicyLate", "PolicyModel", "PolicyServing", "LocalPolicyClient", "STATE_KEY", "image_key"]

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


@attrs.define(kw_only=True)
class PolicyModel(Model):
    """An ONNX policy served by onnxruntime in its own model actor.

    ``local_model_path``: the .onnx file (a path, or a Hugging Face ``owner/name:file.onnx``);
    ``threads``: intra-op threads (policies are small: 1 keeps latency steady);
    ``providers``: execution providers (None: TensorRT or CUDA when present, else CPU);
    ``realtime``: its actor's process at a control loop's priority (:func:`~embagents.realtime.raise_priority`),
    as a VLA with ``realtime=True`` waits on it;
    ``openpi_bind``: its model actor also serves it over openpi's WebSocket protocol there
    (``ws://127.0.0.1:PORT``; beyond loopback with ``openpi_api_key_file``), for
    :class:`~embagents.models.openpi.OpenPIPolicyClient` and openpi's own clients.
    """

    kind: ClassVar[str] = "policy"
    local_model_path: str = ""
    threads: int | None = 1
    providers: list[str] | None = None
    realtime: bool = False
    openpi_bind: str | None = None
    openpi_api_key_file: str | None = None

    def __attrs_post_init__(self) -> None:
        if self.openpi_bind is not None and not self.openpi_bind.startswith("ws://"):
            # (who may listen where is checked when its model actor binds: loopback, else a key)
            raise ValueError(f"policy {self.name!r}: openpi_bind {self.openpi_bind!r} must be ws://HOST:PORT; for "
                             "wss:// serve it with embagents serve-policy --tls-cert/--tls-key")

    def resolve(self) -> str:
        from embagents.models.files.hub import resolve_model_path  # lazy: a cycle

        if not self.local_model_path:
            raise ValueError(f"policy {self.name!r}: needs local_model_path (an .onnx policy file)")
        return resolve_model_path(self.local_model_path, filename_glob="*.onnx")

    def file_problem(self) -> str | None:
        from embagents.models.files.hub import local_file_problem  # lazy: a cycle

        if not self.local_model_path:
            return f"policy {self.name!r}: needs local_model_path (an .onnx policy file)"
        problem = local_file_problem(self.local_model_path)
        if problem and "not found" in problem:
            return (f"policy {self.name!r}: ONNX file {self.local_model_path!r} not found; export your policy to ONNX "
                    "(inputs named by observation keys, e.g. 'observation.state') or build the example's with "
                    "embagents.models.backends.reach_policy.write_reach_policy")
        return problem

    def options(self) -> dict[str, Any]:
        openpi = {"openpi": {"bind": self.openpi_bind, "api_key_file": self.openpi_api_key_file, "name": self.name}} \
            if self.openpi_bind else {}
        return {"threads": self.threads, "providers": self.providers, "realtime": self.realtime, **openpi}


class PolicyServing:
    """An ONNX policy behind the ``act`` task (what a model actor of kind ``policy`` serves)."""

    batchable = False
    _NP = {"tensor(float)": np.float32, "tensor(uint8)": np.uint8, "tensor(double)": np.float64}

    def __init__(self, path: str, options: dict[str, Any]) -> None:
        self.session = OnnxSession(path, threads=options.get("threads"), providers=options.get("providers"))
        self.realtime = bool(options.get("realtime"))
        self.expected = {i.name: (list(i.shape), self._NP.get(i.type, np.float32)) for i in self.session.inputs}

    def load(self) -> None:
        if self.realtime:  # the session (and its threads) exist: the whole process
            import logging


            logging.getLogger("embagents.model").info("serving at %s", raise_priority(whole_process=True))

    def warmup(self) -> None:
        obs = {k: np.zeros([d if isinstance(d, int) else 1 for d in shape[1:]], dtype) for k, (shape, dtype)
               in self.expected.items()}
        self._run(obs)

    def check(self, task: str, inputs: dict[str, Any], options: dict[str, Any]) -> None:
        if task != "act":
            raise BadRequest(f"a policy serves task 'act', not {task!r}")
        obs = inputs.get("observation")
        if not isinstance(obs, dict):
            raise BadRequest("an 'act' request needs inputs {'observation': {key: array}}")
        for key, (shape, _) in self.expected.items():
            value = obs.get(key)
            if not isinstance(value, np.ndarray):
                raise BadRequest(f"observation lacks {key!r} (the policy's inputs: {', '.join(self.expected)}); "
                                 f"keys sent: {', '.join(obs) or 'none'}")
            want = shape[1:] if value.ndim == len(shape) - 1 else shape
            if value.ndim != len(want) or any(isinstance(w, int) and w != g for w, g in zip(want, value.shape, strict=True)):
                raise BadRequest(f"observation {key!r} has shape {tuple(value.shape)}; the policy expects "
                                 f"{tuple(want)} (dims that are names are free)")
        if options:
            raise BadRequest(f"a policy takes no options, got {', '.join(options)}")

    def _run(self, obs: Mapping[str, np.ndarray]) -> np.ndarray:
        feeds = []
        for key, (shape, dtype) in self.expected.items():
            a = np.asarray(obs[key], dtype)
            feeds.append(a[None] if a.ndim == len(shape) - 1 else a)
        out = self.session.run(*feeds)[0]
        return np.asarray(out[0] if out.ndim == 3 and out.shape[0] == 1 else out, np.float32)

    def run(self, task: str, inputs: dict[str, Any], options: dict[str, Any]) -> Iterator[dict[str, Any]]:
        yield {"actions": self._run(inputs["observation"]), "done": True}

    def run_batch(self, task: str, batch: list[dict[str, Any]], options: dict[str, Any]) -> list[dict[str, Any]]:
        raise NotImplementedError("a policy serves one observation at a time")

    def close(self) -> None:
        pass


class LocalPolicyClient:
    """A :class:`PolicyClient` for a :class:`PolicyModel` served by a model actor of this run."""

    in_run = True

    def __init__(self, model: PolicyModel | str) -> None:
        self._client = LocalModelClient(model)
        self.name = self._client.name
        self.model = self._client.model

    def __repr__(self) -> str:
        return f"LocalPolicyClient({self.name!r})"

    def infer(self, observation: Mapping[str, np.ndarray], task: str, timeout_s: float) -> np.ndarray:
        """The policy's chunk for ``observation``; :class:`PolicyLate` after ``timeout_s`` (the request is cancelled).

        ``task`` (the instruction) is not an input of an ONNX policy; language-conditioned ones run on a server.
        """
        self._client.timeout = float(timeout_s)  # this client is this policy's own: no one else waits on it
        try:
            out = self._client.infer("act", {"observation": dict(observation)})
        except ModelUnavailable as exc:
            if type(exc) is ModelUnavailable:
                raise PolicyLate(f"policy {self.name!r} gave no actions within {timeout_s:.3g} s ({exc})") from exc
            raise
        return np.asarray(out["actions"], np.float32)

    def close(self) -> None:
        self._client._drop_conn()
