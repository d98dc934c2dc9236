"""The Memory component against the real embedding model actor (all-MiniLM-L6-v2) and a real SQLite file."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("onnxruntime")
pytest.importorskip("apsw")
pytest.importorskip("sqlite_vec")

from actors import ActorSystem  # noqa: E402
from embagents.components import (  # noqa: E402
    HealthStatus,
    MapEncoding,
    MapLayer,
    Memory,
    MemoryConfig,
    MemoryStore,
)
from embagents.models import LocalModelClient  # noqa: E402
from embagents.models.actor import ModelActor  # noqa: E402
from embagents.msgs import Detections, Odometry, StreamingString, String  # noqa: E402
from embagents.requests import Call  # noqa: E402
from embagents.runtime.component_actor import ComponentActor  # noqa: E402
from embagents.system import (
    load_system,  # noqa: E402
    remember_system,  # noqa: E402
)
from embagents.topic import Topic  # noqa: E402
from supervisor import ChildSpec, SupervisorSpec, start_supervisor  # noqa: E402
from tests.helpers import wait_until  # noqa: E402

odom, seen, notes, said = (Topic("odom", Odometry), Topic("seen", Detections), Topic("notes", String),
                           Topic("said", StreamingString))


@pytest.fixture(scope="module")
def served(minilm_dir: str) -> Iterator[ActorSystem]:
    with ActorSystem() as asys:
        asys.spawn(ModelActor, "minilm", "embedding", minilm_dir, {}, True, wait=60)
        yield asys


@pytest.fixture(scope="module")
def minilm(served: ActorSystem) -> str:
    return "minilm"


def memory(minilm: str, tmp_path: Path, **config: Any) -> Memory:
    mem = Memory(name="memory", position=odom, embedding_client=LocalModelClient(minilm, timeout=30),
                 layers=[MapLayer(subscribes_to=seen, temporal_change=False), MapLayer(subscribes_to=notes),
                         MapLayer(subscribes_to=said)],
                 config=MemoryConfig(db_path=str(tmp_path / "memory.db"), **config))
    mem.attach(lambda topic, msg: None)
    mem.on_configure()
    return mem


def at(mem: Memory, x: float, y: float) -> None:
    mem.on_message("odom", Odometry(position=(x, y, 0.0)))


def feed(mem: Memory, topic: str, msg: Any) -> None:
    assert mem.on_message(topic, msg) and mem.execute()


def detections(*labels: str) -> Detections:
    return Detections(boxes=np.zeros((len(labels), 4), np.float32), labels=list(labels),
                      scores=np.full(len(labels), 0.9, np.float32))


def test_layers_are_stored_where_the_robot_was_and_found_by_meaning(minilm: str, tmp_path: Path) -> None:
    mem = memory(minilm, tmp_path)
    at(mem, 4.0, 2.0)
    feed(mem, "seen", detections("cup", "bottle"))
    feed(mem, "notes", String(data="the kitchen table"))
    at(mem, -3.0, 4.0)
    feed(mem, "seen", detections("book"))
    for part, done in (("the bed", False), ("room", False), ("", True)):
        mem.on_message("said", StreamingString(data=part if not done else "", done=done, stream_id="s1"))
        mem.execute()
    assert mem.count() == 5
    found = mem.locate("cup")
    assert found["found"] and found["text"] == "cup" and found["position"] == [4.0, 2.0, 0.0]
    assert found["near"] == ["the kitchen table"] and "near the kitchen table" in found["summary"]
    assert mem.query("something to read", k=1)[0]["text"] == "book"
    assert [h["text"] for h in mem.near(-3.0, 4.0, radius=0.5)] == ["book", "the bedroom"]
    assert {h["text"] for h in mem.between(-60)} == {"cup", "bottle", "the kitchen table", "book", "the bedroom"}


def test_a_label_seen_again_at_the_same_place_is_not_stored_again(minilm: str, tmp_path: Path) -> None:
    mem = memory(minilm, tmp_path)
    at(mem, 1.0, 1.0)
    feed(mem, "seen", detections("cup"))
    at(mem, 1.2, 1.0)
    feed(mem, "seen", detections("cup"))
    at(mem, 5.0, 1.0)
    feed(mem, "seen", detections("cup"))
    assert mem.count() == 2 and mem.locate("cup")["position"] == [5.0, 1.0, 0.0]  # the latest sighting


def test_locate_answers_the_newest_sighting_of_a_label_stored_more_than_twenty_times(minilm: str,
                                                                                      tmp_path: Path) -> None:
    mem = memory(minilm, tmp_path)
    at(mem, 0.0, 0.0)
    for _ in range(100):
        mem.on_message("notes", String(data="face"))
    assert mem.execute()
    at(mem, 4.0, 2.0)
    for _ in range(29):
        mem.on_message("notes", String(data="face"))
    assert mem.execute()
    assert mem.count() == 129
    found = mem.locate("face")
    assert found["confident"] and found["position"] == [4.0, 2.0, 0.0], found["summary"]


def test_a_query_before_anything_is_stored_says_so(minilm: str, tmp_path: Path) -> None:
    mem = memory(minilm, tmp_path)
    found = mem.locate("cup")
    assert not found["found"] and "nothing is stored" in found["why"] and "seen, notes, said" in found["why"]
    assert mem.query("cup") == [] and mem.near(0, 0, 10) == []
    with pytest.raises(ValueError, match="locate needs what to look for"):
        mem.locate("")


def test_a_store_of_another_embedding_dimension_is_a_system_failure_naming_both(minilm: str, tmp_path: Path) -> None:
    MemoryStore(str(tmp_path / "memory.db"), dim=768, model="mpnet").close()
    mem = memory(minilm, tmp_path)
    assert mem.health_status is HealthStatus.SYSTEM_FAILURE
    text = mem.health.text
    assert "768-dimensional" in text and "'mpnet'" in text and "384-dimensional" in text and "'minilm'" in text
    with pytest.raises(Exception, match="768-dimensional"):
        mem.locate("cup")
    assert MemoryStore(str(tmp_path / "memory.db"), dim=768, model="mpnet").count() == 0  # left as it was


def test_a_corrupt_file_is_set_aside_and_reported(minilm: str, tmp_path: Path) -> None:
    (tmp_path / "memory.db").write_bytes(b"garbage" * 1000)
    mem = memory(minilm, tmp_path)
    assert mem.health_status is HealthStatus.COMPONENT_FAILURE and "moved to" in mem.health.text
    assert any(p.name.startswith("memory.db.corrupt-") for p in tmp_path.iterdir())
    assert mem.remember("works again") == 1


def test_items_arriving_while_the_file_is_locked_are_kept_and_stored_later(minilm: str, tmp_path: Path) -> None:
    mem = memory(minilm, tmp_path)
    mem.remember("before the lock")
    path = str(tmp_path / "memory.db")
    holder = subprocess.Popen([sys.executable, "-c", (
        "import apsw, time\n"
        f"db = apsw.Connection({path!r})\n"
        "db.execute('BEGIN IMMEDIATE')\n"
        "print('locked', flush=True)\n"
        "time.sleep(60)\n")], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "locked"
        assert mem.store is not None
        mem.store.db.set_busy_timeout(100)
        feed(mem, "notes", String(data="during the lock"))
        assert mem.health_status is HealthStatus.COMPONENT_FAILURE and "locked by another process" in mem.health.text
    finally:
        holder.kill()
        holder.wait()
    feed(mem, "notes", String(data="after the lock"))
    assert [h["text"] for h in mem.between(-60)] == ["before the lock", "during the lock", "after the lock"]


def test_a_rate_triggered_step_stores_every_message_since_the_last_tick_where_it_arrived(minilm: str,
                                                                                       tmp_path: Path) -> None:
    enc = MapEncoding(component_name="map", layers=[MapLayer(subscribes_to=notes)], position=odom,
                      db_client=LocalModelClient(minilm), config=MemoryConfig(db_path=str(tmp_path / "m.db")),
                      trigger=15.0)
    enc.attach(lambda topic, msg: None)
    enc.on_configure()
    for i, x in enumerate((1.0, 2.0, 3.0)):
        at(enc, x, 0.0)
        enc.on_message("notes", String(data=f"note {i}"))
    assert enc.execute()  # one tick
    assert [(h["text"], h["position"][0]) for h in enc.between(-60)] == [("note 0", 1.0), ("note 1", 2.0),
                                                                         ("note 2", 3.0)]


def test_an_item_before_any_odometry_is_stored_and_says_so_and_the_map_frame_is_noted(minilm: str,
                                                                                    tmp_path: Path) -> None:
    from embagents.msgs import OccupancyGrid

    grid = Topic("map", OccupancyGrid)
    mem = Memory(name="memory", position=odom, map_topic=grid, embedding_client=LocalModelClient(minilm),
                 layers=[MapLayer(subscribes_to=notes)], config=MemoryConfig(db_path=str(tmp_path / "m.db")))
    mem.attach(lambda topic, msg: None)
    mem.on_configure()
    feed(mem, "notes", String(data="before odometry"))
    mem.on_message("map", OccupancyGrid(frame_id="flat"))
    at(mem, 2.0, 1.0)
    feed(mem, "notes", String(data="with a map"))
    first, second = mem.between(-60)
    assert first["extra"] == {"position_known": False}
    assert second["extra"] == {"map_frame": "flat"} and second["position"] == [2.0, 1.0, 0.0]


def test_map_encoding_keeps_embodied_agents_arguments(minilm: str, tmp_path: Path) -> None:
    enc = MapEncoding(component_name="map_encoder", layers=[MapLayer(subscribes_to=notes)], position=odom,
                      db_client=LocalModelClient(minilm), config=MemoryConfig(db_path=str(tmp_path / "m.db")),
                      trigger=15.0)
    assert enc.name == "map_encoder" and enc.rate_hz == 15.0 and isinstance(enc, Memory)


SYSTEM = '''
from embagents import EmbeddingModel, LocalModelClient, MapLayer, Memory, MemoryConfig, Odometry, String, System, Topic

minilm = EmbeddingModel(name="minilm", local_model_path=MODEL)
memory = Memory(name="memory", position=Topic("odom", Odometry), embedding_client=LocalModelClient(minilm),
                layers=[MapLayer(subscribes_to=Topic("notes", String))], config=MemoryConfig(db_path=DB))
system = System([memory], models=[minilm])
'''


def test_a_restarted_memory_actor_serves_every_item_stored_before_a_sigkill(served: ActorSystem, minilm_dir: str,
                                                                            tmp_path: Path) -> None:
    path = str(tmp_path / "system.py")
    Path(path).write_text(textwrap.dedent(SYSTEM).replace("MODEL", repr(minilm_dir))
                          .replace("DB", repr(str(tmp_path / "memory.db"))))
    remember_system(path, load_system(path))
    asys = served  # its minilm model actor serves the system's memory too
    sup = start_supervisor(asys, SupervisorSpec(intensity=5, period=10, children=[
        ChildSpec("memory", (ComponentActor, (path, "memory")), lifecycle="active"),
    ]))
    try:
        ref = asys.ref("memory")
        acked = [ref.ask(Call("remember", [f"note {i}"]), timeout=30).get() for i in range(40)]
        old = [c.pid for c in sup.which_children() if c.id == "memory"][0]
        os.kill(old, signal.SIGKILL)
        wait_until(lambda: [c.pid for c in sup.which_children() if c.id == "memory"][0] not in (old, "restarting", None), 30)
        assert set(acked) <= set(ref.ask(Call("item_ids"), timeout=30).get())
        assert ref.ask(Call("query", ["note 7"], {"k": 1}), timeout=30).get()[0]["text"] == "note 7"
    finally:
        sup.stop()
