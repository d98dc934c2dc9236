"""The DatasetRecorder: demonstrations from a running system, written as a LeRobot dataset (v3 layout).

Its trigger is the dataset's ``fps``. Between :meth:`DatasetRecorder.start_episode`
(``embagents call recorder start_episode "pick the cup"``, an event, or a
``String`` on a String input) and :meth:`DatasetRecorder.end_episode` (or
``"end"`` on that input) each tick records one frame: the joint state as
``observation.state``, the latest command as ``action``, each camera's
latest image into that camera's video (``observation.images.<camera>``),
with ``timestamp``, ``frame_index``, ``episode_index``, ``index`` and
``task_index``. The layout is LeRobot's dataset v3.0::

    meta/info.json                      features, fps, splits, paths, totals
    meta/stats.json                     per-feature min, max, mean, std, count
    meta/tasks.parquet                  task_index, task
    meta/episodes/chunk-000/file-000.parquet   one row per episode (+ its stats)
    data/chunk-000/file-NNN.parquet     the frames of episode NNN
    videos/observation.images.<camera>/chunk-000/file-NNN.mp4

Parquet through pyarrow, video through PyAV (``pip install 'embagents[dataset]'``).

Bad input: a ``root`` that exists is refused unless ``overwrite=True`` (a
restarted recorder, which finds its own ``meta/.embagents-recording`` mark,
goes on after the episodes already written); a camera with no new frame for
``camera_timeout_s`` ends the episode, marked ``ended_by`` in its row, and
health says which camera stopped.

Example::

    >>> from embagents.msgs import Image, JointState
    >>> from embagents.topic import Topic
    >>> rec = DatasetRecorder(name="recorder", inputs=[Topic("joints", JointState), Topic("command", JointState),
    ...                       Topic("camera", Image)], config=DatasetRecorderConfig(root="/tmp/demo_ds", fps=10,
    ...                       camera_inputs_map={"front": "camera"}, overwrite=True))
    >>> rec.rate_hz
    10.0
"""

from __future__ import annotations

import json
import os
import shutil
import time
from fractions import Fraction
from typing import Any

import numpy as np
from attrs import define, field

from embagents.components.component import Component, ComponentProblem
from embagents.config import BaseComponentConfig, ConfigError, positive_float, to_bool
from embagents.msgs import Image, JointState, String

__all__ = ["DatasetRecorder", "DatasetRecorderConfig", "MARK"]

#: Left in ``meta/`` while a recorder writes the dataset: its restart goes on, anyone else is refused.
MARK = ".embagents-recording"
CODEBASE_VERSION = "v3.0"
CHUNKS_SIZE = 1000
_INSTALL = "pip install 'embagents[dataset]' (pyarrow, av)"


def _str_map(value: object) -> dict[str, str]:
    if not isinstance(value, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in value.items()):
        raise ConfigError(f"expected a dict of name -> name, got {value!r}")
    return dict(value)


@define(kw_only=True)
class DatasetRecorderConfig(BaseComponentConfig):
    """Settings of :class:`DatasetRecorder` (see the module docstring).

    - ``root``: the dataset directory; ``overwrite``: replace it if it exists;
    - ``fps``: frames per second (the trigger);
    - ``state_topic`` / ``action_topic``: the JointState inputs recorded as ``observation.state``
      and ``action`` (default: the first and second JointState inputs); ``joint_names``: the
      joints of both, in order (default: the first command's);
    - ``camera_inputs_map``: camera name -> Image input; ``camera_timeout_s``: a camera
      silent this long ends the episode;
    - ``vcodec`` (``libx264``: h264; LeRobot's own default is ``libsvtav1``), ``crf``, ``robot_type``.
    """

    root: str = ""
    fps: float = field(default=10.0, converter=positive_float)
    state_topic: str = ""
    action_topic: str = ""
    joint_names: list[str] = field(factory=list)
    camera_inputs_map: dict[str, str] = field(factory=dict, converter=_str_map)
    camera_timeout_s: float = field(default=1.0, converter=positive_float)
    overwrite: bool = field(default=False, converter=to_bool)
    vcodec: str = "libx264"
    crf: int = 18
    robot_type: str = ""


def _stats(values: np.ndarray) -> dict[str, Any]:
    """min, max, mean, std over axis 0, and the count."""
    v = values.astype(np.float64)
    return {"min": v.min(0).tolist(), "max": v.max(0).tolist(), "mean": v.mean(0).tolist(), "std": v.std(0).tolist(),
            "count": [int(len(v))]}


def _merge_stats(parts: list[dict[str, Any]]) -> dict[str, Any]:
    """Stats of several episodes as one (weighted mean, pooled variance)."""
    n = np.array([p["count"][0] for p in parts], np.float64)
    mean = np.array([p["mean"] for p in parts], np.float64)
    std = np.array([p["std"] for p in parts], np.float64)
    w = n.reshape((-1,) + (1,) * (mean.ndim - 1)) / n.sum()
    total = (w * mean).sum(0)
    var = (w * (std ** 2 + (mean - total) ** 2)).sum(0)
    return {"min": np.min([p["min"] for p in parts], 0).tolist(), "max": np.max([p["max"] for p in parts], 0).tolist(),
            "mean": total.tolist(), "std": np.sqrt(var).tolist(), "count": [int(n.sum())]}


class _Video:
    """One camera's video of one episode (PyAV), opened at its first frame."""

    def __init__(self, path: str, fps: float, codec: str, crf: int, first: np.ndarray) -> None:
        try:
            import av
        except ImportError as exc:
            raise ModuleNotFoundError(f"writing videos needs PyAV: {_INSTALL}", name="av") from exc
        os.makedirs(os.path.dirname(path), exist_ok=True)
        self.path = path
        self.container = av.open(path, "w")
        stream: Any = self.container.add_stream(codec, rate=Fraction(fps).limit_denominator(1000),
                                                options={"crf": str(crf)} if codec in ("libx264", "libsvtav1") else {})
        self.height, self.width = int(first.shape[0]), int(first.shape[1])
        stream.width, stream.height, stream.pix_fmt = self.width, self.height, "yuv420p"
        self.stream = stream
        self.frames = 0
        self.sums = np.zeros(3)  # per-channel sums for the stats, in [0, 1], on a subsampled grid
        self.squares = np.zeros(3)
        self.lo, self.hi = np.ones(3), np.zeros(3)
        self.pixels = 0

    def add(self, image: np.ndarray) -> None:
        import av

        if image.shape[:2] != (self.height, self.width):
            raise ValueError(f"{self.path}: a frame of shape {image.shape} in a {self.height}x{self.width} video")
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="rgb24")
        frame.pts = self.frames
        for packet in self.stream.encode(frame):
            self.container.mux(packet)
        self.frames += 1
        sample = image[::4, ::4].reshape(-1, 3).astype(np.float64) / 255.0
        self.sums += sample.sum(0)
        self.squares += (sample ** 2).sum(0)
        self.lo, self.hi = np.minimum(self.lo, sample.min(0)), np.maximum(self.hi, sample.max(0))
        self.pixels += len(sample)

    def close(self) -> dict[str, Any]:
        """Flush and close; the per-channel stats (LeRobot's shape: (3, 1, 1))."""
        for packet in self.stream.encode(None):
            self.container.mux(packet)
        self.container.close()
        mean = self.sums / max(1, self.pixels)
        std = np.sqrt(np.maximum(self.squares / max(1, self.pixels) - mean ** 2, 0.0))

        def shaped(v: np.ndarray) -> list[Any]:
            return v.reshape(3, 1, 1).tolist()

        return {"min": shaped(self.lo), "max": shaped(self.hi), "mean": shaped(mean), "std": shaped(std),
                "count": [self.frames]}


class DatasetRecorder(Component):
    """Records episodes of a running system as a LeRobot dataset (see the module docstring)."""

    allowed_inputs = {"Optional": [JointState, Image, String]}
    allowed_outputs = {"Optional": []}
    config_class = DatasetRecorderConfig

    def __init__(self, **kw: Any) -> None:
        self.task: str | None = None
        self.episodes: list[dict[str, Any]] = []  # rows of meta/episodes
        self.tasks: dict[str, int] = {}
        self.total_frames = 0
        self.shapes: dict[str, list[int]] = {}
        self._frames: dict[str, list[Any]] = {}
        self._videos: dict[str, _Video] = {}
        self._waiting = ""
        self._camera_stopped = ""
        self._prepared = False
        super().__init__(**kw)

    def default_trigger(self) -> float:
        return float(self.config.fps)

    # -- declaration ----------------------------------------------------------------------------------------------
    def _state_action_topics(self) -> tuple[str, str]:
        states = [t.name for t in self.inputs if t.msg_type is JointState]
        state = self.config.state_topic or (states[0] if states else "")
        action = self.config.action_topic or next((s for s in states if s != state), "")
        return state, action

    def validate(self) -> list[ComponentProblem]:
        problems = super().validate()
        cfg = self.config
        state, action = self._state_action_topics()
        names = {t.name: t.msg_type for t in self.inputs}
        if not cfg.root:
            problems.append(("bad-config", f"{self._label()}: needs root= (the dataset directory to write)"))
        elif (problem := self._root_problem()) is not None:
            problems.append(("bad-config", problem))
        for what, topic in (("state_topic", state), ("action_topic", action)):
            if names.get(topic) is not JointState:
                problems.append(("bad-config", f"{self._label()}: {what} {topic!r} is not one of its JointState inputs "
                                               "(give it two: the joint states and the commands)"))
        for cam, topic in cfg.camera_inputs_map.items():
            if names.get(topic) is not Image:
                problems.append(("bad-config", f"{self._label()}: camera_inputs_map[{cam!r}] = {topic!r} is not one of "
                                               "its Image inputs"))
        return problems

    def _root_problem(self) -> str | None:
        root = os.path.abspath(self.config.root)
        if not os.path.isdir(root) or not os.listdir(root) or self.config.overwrite:
            return None
        if os.path.exists(os.path.join(root, "meta", MARK)):
            return None  # this recorder's own, being written (a restart goes on)
        return (f"{self._label()}: dataset directory {root} exists; record to a new one (root=) or pass "
                "overwrite=True to replace it")

    # -- lifecycle ------------------------------------------------------------------------------------------------
    def on_configure(self) -> None:
        self._prepare()

    def _prepare(self) -> None:
        if self._prepared:
            return
        root = os.path.abspath(self.config.root)
        problem = self._root_problem()
        if problem is not None:
            raise ValueError(problem)
        mark = os.path.join(root, "meta", MARK)
        if os.path.isdir(root) and os.listdir(root) and not os.path.exists(mark):  # overwrite=True
            shutil.rmtree(root)
        os.makedirs(os.path.join(root, "meta"), exist_ok=True)
        if os.path.exists(mark):
            self._resume(root)
        with open(mark, "w", encoding="utf-8") as f:
            f.write(f"{self.name} pid {os.getpid()}\n")
        self._prepared = True

    def _resume(self, root: str) -> None:
        """A restarted recorder: what was written goes on (the episode it was in when it died is lost)."""
        import pyarrow.parquet as pq

        path = os.path.join(root, "meta", "episodes", "chunk-000", "file-000.parquet")
        if os.path.exists(path):
            self.episodes = pq.read_table(path).to_pylist()
            self.total_frames = sum(int(e["length"]) for e in self.episodes)
        tasks = os.path.join(root, "meta", "tasks.parquet")
        if os.path.exists(tasks):
            self.tasks = {r["task"]: int(r["task_index"]) for r in pq.read_table(tasks).to_pylist()}
        info = os.path.join(root, "meta", "info.json")
        if os.path.exists(info):
            with open(info, encoding="utf-8") as f:
                self.shapes = {k: v["shape"] for k, v in json.load(f)["features"].items()}
        self.logger.info("%s: going on with %s (%d episodes)", self._label(), root, len(self.episodes))

    def on_shutdown(self) -> None:
        if self.task is not None:
            self.end_episode("shutdown")
        mark = os.path.join(os.path.abspath(self.config.root), "meta", MARK)
        if self._prepared and os.path.exists(mark):
            os.unlink(mark)  # a clean stop: the dataset is finished, a later run may not append to it

    # -- episodes -------------------------------------------------------------------------------------------------
    def start_episode(self, task: str = "") -> dict[str, Any]:
        """Start recording an episode of ``task`` (one running is ended first); returns :meth:`status`."""
        if not isinstance(task, str):
            raise ValueError(f"{self._label()}: start_episode needs a task text, got {task!r}")
        self._prepare()
        if self.task is not None:
            self.end_episode("replaced")
        self.task, self._camera_stopped = task, ""
        self.tasks.setdefault(task, len(self.tasks))
        self._frames = {"observation.state": [], "action": []}
        self._videos = {}
        self.logger.info("%s: episode %d started: %r", self._label(), len(self.episodes), task)
        return self.status()

    def end_episode(self, ended_by: str = "call") -> dict[str, Any]:
        """End the episode: its frames, videos and metadata are written; returns :meth:`status`."""
        if self.task is None:
            return self.status()
        self._write_episode(ended_by)
        self.task = None
        return self.status()

    def status(self) -> dict[str, Any]:
        """``{"recording", "task", "frames", "episodes", "total_frames", "root"}``."""
        return {"recording": self.task is not None, "task": self.task,
                "frames": len(self._frames.get("action", [])) if self.task is not None else 0,
                "episodes": len(self.episodes), "total_frames": self.total_frames,
                "root": os.path.abspath(self.config.root)}

    def on_message(self, topic_name: str, msg: Any, now: float | None = None) -> bool:
        if isinstance(msg, String) and any(t.name == topic_name and t.msg_type is String for t in self.inputs):
            text = msg.data.strip()
            if text.lower() in ("end", "stop"):
                self.end_episode("topic")
            elif text:
                self.start_episode(text)
        return super().on_message(topic_name, msg, now)

    # -- the frames -----------------------------------------------------------------------------------------------
    def _execution_step(self, **inputs: Any) -> None:
        if self.task is None:
            if self._camera_stopped:  # said until the next episode starts
                self.set_system_failure(self._camera_stopped)
            return
        now = time.monotonic()
        for cam, topic in self.config.camera_inputs_map.items():
            at = self._received_at.get(topic)
            if at is not None and now - at > self.config.camera_timeout_s and self._frames["action"]:
                text = (f"camera {cam!r} ({topic}) stopped: no frame for {now - at:.1f} s (camera_timeout_s "
                        f"{self.config.camera_timeout_s}); episode {len(self.episodes)} ended and marked")
                self.logger.warning("%s: %s", self._label(), text)
                self.end_episode(f"camera {cam!r} stopped")
                self._camera_stopped = text
                self.set_system_failure(text)
                return
        state_topic, action_topic = self._state_action_topics()
        state, action = inputs.get(state_topic), inputs.get(action_topic)
        images = {cam: inputs.get(topic) for cam, topic in self.config.camera_inputs_map.items()}
        missing = [n for n, v in ((state_topic, state), (action_topic, action), *images.items()) if v is None]
        if missing:  # at an episode's start: the first command or frame is still on its way
            if self._waiting != str(missing):
                self.logger.info("%s: waiting for %s before the first frame", self._label(), ", ".join(missing))
                self._waiting = str(missing)
            return
        self._waiting = ""
        assert state is not None and action is not None  # (none is missing)
        joints = self.config.joint_names or list(action.name)  # the joints commanded (a gripper's fingers may not be)
        self.config.joint_names = joints
        self._frames["observation.state"].append(self._vector(state, joints, "position", state_topic))
        self._frames["action"].append(self._vector(action, joints, "position", action_topic))
        for cam, img in images.items():
            assert img is not None
            key = f"observation.images.{cam}"
            video = self._videos.get(key)
            if video is None:
                path = os.path.join(os.path.abspath(self.config.root), "videos", key, "chunk-000",
                                    f"file-{len(self.episodes):03d}.mp4")
                video = self._videos[key] = _Video(path, self.config.fps, self.config.vcodec, self.config.crf, img.data)
            video.add(img.data)

    def _vector(self, js: JointState, joints: list[str], field_name: str, topic: str) -> np.ndarray:
        values = getattr(js, field_name)
        index = {n: i for i, n in enumerate(js.name)}
        if any(j not in index for j in joints) or len(values) != len(js.name):
            raise ValueError(f"{topic}: joint state lacks {[j for j in joints if j not in index] or 'positions'}; "
                             f"it has {js.name}")
        return values[[index[j] for j in joints]].astype(np.float32)

    # -- writing --------------------------------------------------------------------------------------------------
    def _write_episode(self, ended_by: str) -> None:
        try:
            import pyarrow as pa
            import pyarrow.parquet as pq
        except ImportError as exc:
            raise ModuleNotFoundError(f"writing a dataset needs pyarrow: {_INSTALL}", name="pyarrow") from exc
        root = os.path.abspath(self.config.root)
        ep = len(self.episodes)
        n = len(self._frames["action"])
        video_stats = {key: v.close() for key, v in self._videos.items()}
        if n == 0:
            for v in self._videos.values():
                os.unlink(v.path)
            self.logger.info("%s: episode %d had no frames: not written", self._label(), ep)
            return
        fps = float(self.config.fps)
        state = np.stack(self._frames["observation.state"])
        action = np.stack(self._frames["action"])
        frame_index = np.arange(n, dtype=np.int64)
        timestamp = (frame_index / fps).astype(np.float32)
        start = self.total_frames
        columns = {
            "observation.state": pa.array(list(state), type=pa.list_(pa.float32(), state.shape[1])),
            "action": pa.array(list(action), type=pa.list_(pa.float32(), action.shape[1])),
            "timestamp": pa.array(timestamp), "frame_index": pa.array(frame_index),
            "episode_index": pa.array(np.full(n, ep, np.int64)), "index": pa.array(start + frame_index),
            "task_index": pa.array(np.full(n, self.tasks[self.task or ""], np.int64)),
        }
        data_path = os.path.join(root, "data", "chunk-000", f"file-{ep:03d}.parquet")
        os.makedirs(os.path.dirname(data_path), exist_ok=True)
        pq.write_table(pa.table(columns), data_path)
        stats = {"observation.state": _stats(state), "action": _stats(action),
                 "timestamp": _stats(timestamp[:, None]), "frame_index": _stats(frame_index[:, None]),
                 "episode_index": _stats(np.full((n, 1), ep)), "index": _stats((start + frame_index)[:, None]),
                 "task_index": _stats(np.full((n, 1), self.tasks[self.task or ""])), **video_stats}
        row: dict[str, Any] = {"episode_index": ep, "tasks": [self.task or ""], "length": n,
                               "data/chunk_index": 0, "data/file_index": ep,
                               "dataset_from_index": start, "dataset_to_index": start + n,
                               "meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0,
                               "embagents/ended_by": ended_by}
        for key, video in self._videos.items():
            row.update({f"videos/{key}/chunk_index": 0, f"videos/{key}/file_index": ep,
                        f"videos/{key}/from_timestamp": 0.0, f"videos/{key}/to_timestamp": n / fps})
            self.shapes[key] = [video.height, video.width, 3]
        for feature, s in stats.items():
            for name, value in s.items():
                row[f"stats/{feature}/{name}"] = value  # a list column per stat, as LeRobot's episodes file has
        self.shapes["observation.state"] = [int(state.shape[1])]
        self.shapes["action"] = [int(action.shape[1])]
        self.episodes.append(row)
        self.total_frames += n
        self._write_meta(root)
        self.logger.info("%s: episode %d written: %d frames (%s)", self._label(), ep, n, ended_by)

    def _write_meta(self, root: str) -> None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        episodes = os.path.join(root, "meta", "episodes", "chunk-000", "file-000.parquet")
        os.makedirs(os.path.dirname(episodes), exist_ok=True)
        keys = sorted({k for row in self.episodes for k in row})
        pq.write_table(pa.Table.from_pylist([{k: row.get(k) for k in keys} for row in self.episodes]), episodes)
        tasks = pa.table({"task_index": pa.array(list(self.tasks.values()), pa.int64()), "task": pa.array(list(self.tasks))})
        # LeRobot reads this file with pandas, the task text as its index: say so as pandas itself would
        pandas = {"index_columns": ["task"], "column_indexes": [], "creator": {"library": "pyarrow", "version": pa.__version__},
                  "columns": [{"name": "task_index", "field_name": "task_index", "pandas_type": "int64",
                               "numpy_type": "int64", "metadata": None},
                              {"name": "task", "field_name": "task", "pandas_type": "unicode", "numpy_type": "object",
                               "metadata": None}], "pandas_version": "2.2.0"}
        pq.write_table(tasks.replace_schema_metadata({b"pandas": json.dumps(pandas).encode()}),
                       os.path.join(root, "meta", "tasks.parquet"))
        joints = self.config.joint_names
        features: dict[str, Any] = {
            "observation.state": {"dtype": "float32", "shape": self.shapes.get("observation.state", [len(joints)]),
                                  "names": joints},
            "action": {"dtype": "float32", "shape": self.shapes.get("action", [len(joints)]), "names": joints},
        }
        fps = float(self.config.fps)
        for cam in self.config.camera_inputs_map:
            key = f"observation.images.{cam}"
            shape = self.shapes.get(key, [0, 0, 3])
            features[key] = {"dtype": "video", "shape": shape, "names": ["height", "width", "channels"],
                             "info": {"video.height": shape[0], "video.width": shape[1],
                                      "video.codec": {"libx264": "h264", "libsvtav1": "av1"}.get(self.config.vcodec,
                                                                                                  self.config.vcodec),
                                      "video.pix_fmt": "yuv420p", "video.is_depth_map": False, "video.fps": fps,
                                      "video.channels": 3, "has_audio": False}}
        for name, dtype in (("timestamp", "float32"), ("frame_index", "int64"), ("episode_index", "int64"),
                            ("index", "int64"), ("task_index", "int64")):
            features[name] = {"dtype": dtype, "shape": [1], "names": None}
        info = {
            "codebase_version": CODEBASE_VERSION, "robot_type": self.config.robot_type or None,
            "total_episodes": len(self.episodes), "total_frames": self.total_frames, "total_tasks": len(self.tasks),
            "chunks_size": CHUNKS_SIZE, "data_files_size_in_mb": 100, "video_files_size_in_mb": 500, "fps": fps,
            "splits": {"train": f"0:{len(self.episodes)}"},
            "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
            "video_path": "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
            if self.config.camera_inputs_map else None,
            "features": features,
        }
        merged: dict[str, Any] = {}
        for feature in {k.split("/")[1] for row in self.episodes for k in row if k.startswith("stats/")}:
            parts = [{s: row[f"stats/{feature}/{s}"] for s in ("min", "max", "mean", "std", "count")}
                     for row in self.episodes if f"stats/{feature}/mean" in row]
            merged[feature] = _merge_stats(parts)
        for name, value in (("info.json", info), ("stats.json", merged)):
            tmp = os.path.join(root, "meta", f".{name}.tmp")
            with open(tmp, "w", encoding="utf-8") as f:
                json.dump(value, f, indent=2)
            os.replace(tmp, os.path.join(root, "meta", name))  # a reader never sees half a file
