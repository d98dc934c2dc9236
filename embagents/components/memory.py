"""The Memory component: what the robot saw and heard, where and when, kept across restarts.

Inputs: an ``Odometry`` topic (where the robot is), optionally an
``OccupancyGrid`` (the map, kept as the frame of positions), and *layers*:
``String``, ``StreamingString`` (a stream is one item once ``done``),
``Detections`` (one item per label, e.g. "cup") or ``RosMessage`` (a bridged
ROS message such as a battery state: its fields as text) topics. Each item is stored
with the robot's position, the time, its layer and its embedding (an
embedding client: ``LocalModelClient(EmbeddingModel(...))`` or
:class:`~embagents.models.clients.OpenAIEmbeddingClient`) in a SQLite file
(:mod:`embagents.components.memory_store`). A stored item is committed
before the step returns, so it survives a SIGKILL.

Queries (actions: callable from events, other components and, through
:func:`~embagents.components.llm_tools.register_tools_on`, an LLM): :meth:`Memory.query`
(top k by meaning), :meth:`Memory.near` (within a radius of a point),
:meth:`Memory.between` (a time window), :meth:`Memory.locate` (where
something was last seen), :meth:`Memory.remember` (store a note now).

Example::

    >>> from embagents.msgs import Detections, Odometry, String
    >>> from embagents.topic import Topic
    >>> class Toy:                              # an embedding client: texts -> unit vectors
    ...     name = "toy"
    ...     def embed(self, texts):
    ...         import numpy as np
    ...         return np.array([[1.0, 0.0] if "cup" in t else [0.0, 1.0] for t in texts], np.float32)
    >>> import tempfile
    >>> mem = Memory(name="memory", position=Topic("odom", Odometry),
    ...              layers=[MapLayer(subscribes_to=Topic("seen", Detections))], embedding_client=Toy(),
    ...              config=MemoryConfig(db_path=tempfile.mkdtemp() + "/m.db"))
    >>> mem.on_configure()
    >>> mem.on_message("odom", Odometry(position=(2.0, 3.0, 0.0))); mem.remember("a red cup")
    False
    1
    >>> mem.locate("cup")["position"]
    [2.0, 3.0, 0.0]
"""

from __future__ import annotations

import os
import time
from collections import deque
from collections.abc import Sequence
from typing import Any

from attrs import define, field

from embagents.components.component import Component, ComponentProblem
from embagents.components.memory_store import (
    MemoryDimensionError,
    MemoryLocked,
    MemoryStore,
    MemoryStoreError,
)
from embagents.config import BaseComponentConfig, one_of, positive_float, positive_int
from embagents.models.files.wheels import cache_dir
from embagents.msgs import Detections, OccupancyGrid, Odometry, RosMessage, StreamingString, String
from embagents.topic import Topic

__all__ = ["MapConfig", "MapEncoding", "MapLayer", "Memory", "MemoryConfig", "embedding_dim"]

_LAYER_TYPES = (String, StreamingString, Detections, RosMessage)


@define(kw_only=True)
class MapLayer:
    """One layer of memory: what a topic says, stored where the robot was when it said it.

    ``temporal_change``: keep every change over time (False: a Detections label
    already stored within ``resolution_m`` of here is not stored again).
    ``resolution_m``: the distance (metres) under which a repeated label counts as the same sighting.
    """

    subscribes_to: Topic
    temporal_change: bool = True
    resolution_m: float = field(default=0.5, converter=positive_float)

    @property
    def name(self) -> str:
        return self.subscribes_to.name


def _durability(value: object) -> str:
    return one_of("durability", "normal", "full", meanings={"normal": "survives a crash", "full": "also a power loss"})(value)


@define(kw_only=True)
class MemoryConfig(BaseComponentConfig):
    """Settings of :class:`Memory`.

    - ``db_path``: the SQLite file (None: ``<cache>/memory/<map_name>.db``).
    - ``map_name``: the memory's name (EmbodiedAgents' ``map_name``).
    - ``durability``: ``"normal"`` (WAL + synchronous=NORMAL: a committed item
      survives a crash of the process) or ``"full"`` (an fsync per commit: also a power loss).
    - ``locate_max_distance``: cosine distance under which a stored item counts as
      the thing ``locate`` looks for (all-MiniLM-L6-v2: "cup" to "mug" 0.29, to
      "bottle" 0.51); of those within 0.1 of the best match, the latest wins.
    - ``max_pending``: items kept in RAM while the database is locked elsewhere.
    - ``near_m``: ``locate`` also names what other layers stored this close (metres) to the find.

    >>> MemoryConfig(durability="full").durability
    'full'
    """

    db_path: str | None = None
    map_name: str = "memory"
    durability: str = field(default="normal", converter=_durability)
    locate_max_distance: float = field(default=0.35, converter=positive_float)
    max_pending: int = field(default=10000, converter=positive_int)
    near_m: float = field(default=1.5, converter=positive_float)


def embedding_dim(client: Any) -> int:
    """The dimension of ``client``'s embeddings (one tiny request)."""
    return int(client.embed(["dimension probe"]).shape[1])


def _client_name(client: Any) -> str:
    name = getattr(client, "name", None)
    return name if isinstance(name, str) and name else type(client).__name__


class Memory(Component):
    """Stores layers of what the robot perceives with position, time and meaning (module docstring)."""

    #: The actions :func:`~embagents.components.llm_tools.register_tools_on` offers an LLM.
    llm_tools: tuple[str, ...] = ("locate", "query", "near", "between")

    # Odometry is checked in validate(), not Required: a layer's message before the first
    # odometry is still stored (position_known False), not held back.
    allowed_inputs = {"Optional": [Odometry, OccupancyGrid, String, StreamingString, Detections, RosMessage]}
    allowed_outputs = None
    config_class = MemoryConfig

    def __init__(self, *, name: str, layers: Sequence[MapLayer] = (), position: Topic | None = None,
                 map_topic: Topic | None = None, embedding_client: Any = None, **kw: Any) -> None:
        self.layers = list(layers)
        self.position_topic, self.map_topic = position, map_topic
        self.embedding_client = embedding_client
        # models_of() starts the model actor a LocalModelClient names.
        self.clients = {} if embedding_client is None else {_client_name(embedding_client): embedding_client}
        self.store: MemoryStore | None = None
        self.store_problem: str | None = None
        self._pending: deque[tuple[str, str, Any, tuple[float, float, float], float, dict[str, Any] | None]] = deque()
        self._streams: dict[tuple[str, str], list[str]] = {}
        self._where: tuple[float, float, float] | None = None
        self._grid: OccupancyGrid | None = None
        self._by_topic = {layer.name: layer for layer in self.layers}
        self._inbox: list[tuple[str, str, dict[str, Any] | None, tuple[float, float, float], float]] = []
        inputs = [t for t in (position, map_topic) if t is not None] + [layer.subscribes_to for layer in self.layers]
        super().__init__(name=name, inputs=kw.pop("inputs", inputs), **kw)

    def default_trigger(self) -> list[Topic] | None:
        """Any layer's message runs a step (it is stored)."""
        return [layer.subscribes_to for layer in self.layers] or None

    def validate(self) -> list[ComponentProblem]:
        problems = super().validate()
        if self.embedding_client is None or not callable(getattr(self.embedding_client, "embed", None)):
            problems.append(("missing-client", f"{self._label()}: needs an embedding_client with embed(texts), e.g. "
                                               "LocalModelClient(EmbeddingModel(name='minilm'))"))
        if self.position_topic is None or self.position_topic.msg_type is not Odometry:
            problems.append(("bad-input", f"{self._label()}: position must be an Odometry topic (where the robot is)"))
        names = [layer.name for layer in self.layers]
        for layer in self.layers:
            if layer.subscribes_to.msg_type not in _LAYER_TYPES:
                problems.append(("bad-input", f"{self._label()}: layer {layer.name!r} is a "
                                              f"{getattr(layer.subscribes_to.msg_type, '__name__', '?')} topic; layers are "
                                              "String, StreamingString, Detections or RosMessage topics"))
        if len(set(names)) != len(names):
            problems.append(("bad-input", f"{self._label()}: two layers read the same topic"))
        return problems

    # --- lifecycle ----------------------------------------------------------------------------
    @property
    def db_path(self) -> str:
        if self.config.db_path:
            return os.path.abspath(os.path.expanduser(self.config.db_path))

        return str(cache_dir() / "memory" / f"{self.config.map_name}.db")

    def on_configure(self) -> None:
        """Open the database (an unreadable file is set aside, a locked one retried at each step)."""
        self._open()

    def _open(self) -> bool:
        if self.store is not None:
            return True
        try:
            self.store = MemoryStore(self.db_path, dim=embedding_dim(self.embedding_client),
                                     model=_client_name(self.embedding_client), durability=self.config.durability)
        except MemoryLocked as exc:
            self._fail(str(exc), system=False)
            return False
        except MemoryDimensionError as exc:
            self._fail(str(exc), system=True)
            return False
        if self.store.set_aside:
            self._fail(f"the memory file was unreadable: moved to {self.store.set_aside} (kept, not emptied); "
                       f"a new memory started at {self.db_path}", system=False)
        elif self.store_problem is not None:
            self.store_problem = None
            self.set_healthy()
        self.logger.info("%s: memory %s holds %d items", self._label(), self.db_path, self.store.count())
        return True

    def _fail(self, text: str, *, system: bool) -> None:
        self.store_problem = text
        self.logger.error("%s: %s", self._label(), text)
        (self.set_system_failure if system else self.set_component_failure)(text)

    def on_shutdown(self) -> None:
        if self.store is not None:
            self.store.close()
            self.store = None

    # --- input --------------------------------------------------------------------------------
    def on_message(self, topic_name: str, msg: Any, now: float | None = None) -> bool:
        if isinstance(msg, Odometry) and self.position_topic is not None and topic_name == self.position_topic.name:
            self._where = tuple(float(c) for c in msg.position)  # type: ignore[assignment]
        elif isinstance(msg, OccupancyGrid):
            self._grid = msg
        layer = self._by_topic.get(topic_name)
        if layer is not None:
            # Taken now, where the robot is now: a rate-triggered step (MapEncoding's trigger=15.0)
            # stores every message since the last tick, not only the latest of each topic.
            where, note = self._position()
            for name, text, extra in self._items_of(layer, msg):
                self._inbox.append((name, text, {**(extra or {}), **(note or {})} or None, where, time.time()))
        return super().on_message(topic_name, msg, now)

    def _execution_step(self, **inputs: Any) -> None:
        items, self._inbox = self._inbox, []
        self._store(items)

    def _items_of(self, layer: MapLayer, msg: Any) -> list[tuple[str, str, dict[str, Any] | None]]:
        if isinstance(msg, String):
            return [(layer.name, msg.data, None)] if msg.data.strip() else []
        if isinstance(msg, StreamingString):
            key = (layer.name, msg.stream_id)
            parts = self._streams.setdefault(key, [])
            parts.append(msg.data)
            if not msg.done:
                return []
            text = "".join(self._streams.pop(key))
            return [(layer.name, text, {"stream_id": msg.stream_id})] if text.strip() else []
        if isinstance(msg, Detections):
            out: list[tuple[str, str, dict[str, Any] | None]] = []
            for label, score in zip(msg.labels, [float(s) for s in msg.scores], strict=False):
                if not layer.temporal_change and self._seen_here(layer, label):
                    continue
                out.append((layer.name, label, {"score": round(score, 3), "frame_id": msg.frame_id}))
            return out
        if isinstance(msg, RosMessage):  # a bridged ROS message (a battery state): its fields as text
            shown = ", ".join(f"{k}={v}" for k, v in msg.fields.items() if isinstance(v, (str, int, float, bool)))
            return [(layer.name, f"{layer.name}: {shown}", {"ros_type": msg.ros_type})] if shown else []
        return []

    def _seen_here(self, layer: MapLayer, label: str) -> bool:
        if self.store is None or self._where is None:
            return False
        return any(it["text"] == label for it in self.store.within(self._where, layer.resolution_m, layer=layer.name))

    def _position(self) -> tuple[tuple[float, float, float], dict[str, Any] | None]:
        """Where the robot is, and notes for the item: no odometry yet, or the map's frame it is in."""
        note: dict[str, Any] = {}
        if self._grid is not None:
            note["map_frame"] = self._grid.frame_id
        if self._where is None:
            return (0.0, 0.0, 0.0), {**note, "position_known": False}
        return self._where, note or None

    def _store(self, items: list[tuple[str, str, dict[str, Any] | None, tuple[float, float, float], float]]) -> list[int]:
        """Embed ``items`` (layer, text, extra, position, time) and commit them with any kept from before."""
        if not items and not self._pending:
            return []
        if items:
            vectors = self.embedding_client.embed([text for _, text, _, _, _ in items])
            for (layer, text, extra, where, t), v in zip(items, vectors, strict=True):
                self._pending.append((layer, text, v, where, t, extra))
        while len(self._pending) > self.config.max_pending:
            dropped = self._pending.popleft()
            self.logger.error("%s: memory locked for too long: dropped %r (max_pending %d)", self._label(), dropped[1],
                              self.config.max_pending)
        if not self._open():
            return []
        assert self.store is not None
        try:
            ids = self.store.add_many(list(self._pending))
        except MemoryStoreError as exc:  # locked by another writer meanwhile: keep them, try next step
            self._fail(str(exc), system=False)
            return []
        self._pending.clear()
        return ids

    # --- actions ------------------------------------------------------------------------------
    def _ready(self) -> MemoryStore:
        if not self._open() or self.store is None:
            raise MemoryStoreError(self.store_problem or "the memory database is not open")
        return self.store

    def remember(self, text: str, layer: str = "notes") -> int:
        """Store ``text`` now, at the robot's current position; returns the item's id (committed).

        Example: ``remember("the charger is behind the sofa")``.
        """
        if not isinstance(text, str) or not text.strip():
            raise ValueError(f"remember needs a non-empty text, got {text!r}")
        where, note = self._position()
        ids = self._store([(layer, text, note, where, time.time())])
        if not ids:
            raise MemoryStoreError(f"not stored yet (kept in RAM, {len(self._pending)} pending): {self.store_problem}")
        return ids[-1]

    def count(self) -> int:
        """How many items the memory holds."""
        return self._ready().count()

    def item_ids(self) -> list[int]:
        """The ids of every stored item (for checks after a crash)."""
        return self._ready().ids()

    def query(self, text: str, k: int = 5, layer: str | None = None) -> list[dict[str, Any]]:
        """What the robot remembers about a topic: the stored items closest in meaning.

        Returns the ``k`` items nearest in meaning to ``text`` (with position, time, layer, distance).
        """
        store = self._ready()
        return store.semantic(self.embedding_client.embed([text])[0], k=int(k), layer=layer)

    def near(self, x: float, y: float, radius: float = 1.0, layer: str | None = None) -> list[dict[str, Any]]:
        """What was stored near a point (x, y in metres).

        Items stored within ``radius`` metres of (``x``, ``y``), nearest first.
        """
        return self._ready().within((float(x), float(y)), float(radius), layer=layer)

    def between(self, start: float, end: float | None = None, layer: str | None = None) -> list[dict[str, Any]]:
        """What was stored in a time window (seconds; a negative start means that many seconds ago).

        ``start`` and ``end`` are Unix seconds; a negative ``start`` means "that many seconds
        ago", ``end`` None means now.
        """
        now = time.time()
        t0 = now + float(start) if float(start) < 0 else float(start)
        return self._ready().between(t0, now if end is None else float(end), layer=layer)

    def locate(self, what: str) -> dict[str, Any]:
        """Where an object was last seen, and when.

        The latest item close enough in meaning to ``what`` (else the closest).

        Returns ``{"found": True, "what", "text", "position", "time", "seconds_ago", "layer", "distance",
        "near", "summary"}`` (``near``: texts of other layers stored within ``near_m`` of that place,
        such as a note naming the room), or ``{"found": False, "why", "summary"}`` when nothing is stored yet.
        """
        if not isinstance(what, str) or not what.strip():
            raise ValueError(f"locate needs what to look for (a non-empty text, e.g. 'cup'), got {what!r}")
        store = self._ready()
        if store.count() == 0:
            why = (f"nothing is stored in memory {self.config.map_name!r} yet; layers: "
                   f"{', '.join(layer.name for layer in self.layers) or 'none'}")
            return {"found": False, "what": what, "why": why, "summary": f"I have not seen {what}: {why}"}
        vector = self.embedding_client.embed([what])[0]
        closest = store.semantic(vector, k=1)[0]
        # The same thing seen again (as close in meaning as the best match, give or take 0.1): the newest of
        # all such items wins, not of the top k (a label stored 100 times would hide its latest sightings).
        cutoff = min(self.config.locate_max_distance, closest["distance"] + 0.1)
        latest = store.latest_similar(vector, cutoff) if closest["distance"] <= cutoff else None
        close = latest is not None
        best = latest if latest is not None else closest
        x, y = best["position"][0], best["position"][1]
        near = [it["text"] for it in store.within((x, y), self.config.near_m)
                if it["layer"] != best["layer"] and it["id"] != best["id"]]
        near = list(dict.fromkeys(near))[:3]
        ago = round(time.time() - best["time"], 1)
        summary = "" if close else f"nothing quite like {what!r} is stored; the closest is "
        summary += f"I last saw {best['text']} {ago:.0f} s ago at x={x:.1f}, y={y:.1f}"
        summary += f", near {'; '.join(near)}" if near else ""
        return {"found": True, "what": what, "text": best["text"], "position": best["position"],
                "time": best["time"], "seconds_ago": ago, "layer": best["layer"],
                "distance": round(best["distance"], 3), "confident": bool(close), "near": near, "summary": summary}

    def snapshot(self) -> Any:
        return None  # everything lives in the database file


#: EmbodiedAgents' name for the map memory's config.
MapConfig = MemoryConfig


class MapEncoding(Memory):
    """EmbodiedAgents' ``MapEncoding``, built on :class:`Memory`: same arguments, ``component_name`` for ``name``.

    ``db_client`` is EmbodiedAgents' vector-database client; here the database is
    built in, so it names the embedding client instead (``embedding_client`` works too).
    With a rate ``trigger`` (EmbodiedAgents' ``trigger=15.0``), each tick stores what
    the layers said since the last tick.

    Example::

        >>> MapEncoding(component_name="map", layers=[MapLayer(subscribes_to=Topic("notes", String))],
        ...             position=Topic("odom", Odometry), db_client=None).name        # doctest: +SKIP
        'map'
    """

    def __init__(self, *, component_name: str | None = None, name: str | None = None, db_client: Any = None,
                 **kw: Any) -> None:
        kw.setdefault("embedding_client", db_client)
        super().__init__(name=str(component_name or name or "map_encoding"), **kw)
