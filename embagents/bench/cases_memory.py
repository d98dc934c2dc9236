"""Understanding and remembering: ``router_latency``, ``memory_scale`` and ``memory_crash``.

- ``router_latency``: a ``String`` published in this process goes through
  the SemanticRouter component (an actor process) and the all-MiniLM-L6-v2
  model actor (another) and comes back routed; against the same model and
  routing called in one process (a subprocess: onnxruntime must not load in
  this one, whose later ActorSystems fork from it). Interleaved, one text in
  flight. ``ratio`` = runtime p50 / in-process p50. ``pyzmq_ratio``: the
  same three processes and four hops on raw pyzmq and msgpack (blocking
  recv, no supervision, no checks), interleaved in the same run: the floor
  that this machine's wake-ups put under any multi-process router;
  ``over_pyzmq_us``: what the runtime adds to it per text.
- ``memory_scale``: the memory database (:class:`~embagents.components.MemoryStore`,
  SQLite WAL) filled with 100,000 items (384-dimensional unit vectors,
  clustered like sentence embeddings, positions on a 100 m square); semantic
  top-10 and radius (the nearest 10 within 2 m) queries timed at 1,000 and at
  100,000 items. ``query_p50_ms_*`` is the slower of the two kinds' p50;
  ``recall_at_10``: the share of the exact top 10 the semantic query found.
- ``memory_crash``: a supervised Memory actor is SIGKILLed while items stream
  in (``remember`` asks from this process); the supervisor restarts it; ``lost``
  = items whose ask was answered (committed) before the kill but are missing after.
"""

from __future__ import annotations

import os
import queue
import signal
import statistics
import tempfile
import textwrap
import threading
import time
from functools import partial
from typing import Any

import numpy as np

from actors import Actor, ActorSystem
from actors.topics import Publisher, Subscription
from embagents.bench.registry import Baseline, BenchOptions, case
from embagents.components import Route, SemanticRouter, SemanticRouterConfig
from embagents.components.memory_store import MemoryStore
from embagents.models import LocalModelClient
from embagents.models.actor import ModelActor
from embagents.models.backends.embeddings import prepared_minilm
from embagents.msgs import String
from embagents.requests import Call
from embagents.runtime.component_actor import ComponentActor
from embagents.system import load_system, remember_system
from embagents.topic import Topic
from supervisor import ChildSpec, SupervisorSpec, start_supervisor

__all__ = ["RouterHost"]  # actor classes the fork server imports by name

ROUTES = {
    "bench_goto": ["go to the kitchen", "drive to the front door", "move to the bedroom"],
    "bench_chat": ["hello, how are you?", "tell me a joke", "what is your name?"],
    "bench_look": ["what do you see?", "look at the table", "describe the room"],
}
TEXTS = ["please drive to the living room", "hi there, how is it going?", "can you see a cup on the table?",
         "go over to the window", "tell me something funny", "what is in front of you?"]


class RouterHost(Actor):
    """A SemanticRouter on topic ``bench_heard`` with the :data:`ROUTES`, embeddings from ``model``."""

    def __init__(self, model: str) -> None:
        self.model = model

    def on_start(self) -> None:
        routes = [Route(routes_to=Topic(name, String), samples=s) for name, s in ROUTES.items()]
        self.router = SemanticRouter(name=self.name, inputs=[Topic("bench_heard", String)], routes=routes,
                                     embedding_client=LocalModelClient(self.model),
                                     config=SemanticRouterConfig(maximum_distance=2.0))
        self.router.attach(lambda topic, msg: self.context.publish(topic, msg))
        self.router.on_configure()
        self.context.subscribe("bench_heard", self._on_text, queue_size=10, keep="all")

    def _on_text(self, msg: Any) -> None:
        if self.router.on_message("bench_heard", msg):
            self.router.execute()


_BASELINE = """
import sys, time
import numpy as np
from embagents.bench.cases_memory import ROUTES
from embagents.models.backends.embeddings import SentenceEncoder
enc = SentenceEncoder(sys.argv[1])
names = [n for n, s in ROUTES.items() for _ in s]
vecs = enc.embed([x for s in ROUTES.values() for x in s])
for line in sys.stdin:
    t0 = time.monotonic()
    d = np.sqrt(np.maximum(2 - 2 * (vecs @ enc.embed([line.strip()])[0]), 0))
    route = names[int(np.argmin(d))]
    print(time.monotonic() - t0, route, flush=True)
"""


# The same topology on raw pyzmq: a driver (asked a line at a time) -> router process -> model process -> back.
_RAW_MODEL = """
import sys, msgpack, zmq
from embagents.models.backends.embeddings import SentenceEncoder
enc = SentenceEncoder(sys.argv[1])
enc.embed(["warm up"])
sock = zmq.Context().socket(zmq.ROUTER)
sock.bind(sys.argv[2] + "/model")
while True:
    ident, data = sock.recv_multipart()
    sock.send_multipart([ident, enc.embed(msgpack.unpackb(data)).tobytes()])
"""
_RAW_ROUTER = """
import sys, msgpack, zmq
import numpy as np
from embagents.bench.cases_memory import ROUTES
ctx = zmq.Context()
inbox, outbox, model = ctx.socket(zmq.PULL), ctx.socket(zmq.PUSH), ctx.socket(zmq.DEALER)
inbox.bind(sys.argv[1] + "/in")
outbox.connect(sys.argv[1] + "/out")
model.connect(sys.argv[1] + "/model")
def embed(texts):
    model.send(msgpack.packb(texts))
    return np.frombuffer(model.recv(), np.float32).reshape(len(texts), -1)
names = [n for n, s in ROUTES.items() for _ in s]
vecs = embed([x for s in ROUTES.values() for x in s])
while True:
    text = msgpack.unpackb(inbox.recv())
    d = np.sqrt(np.maximum(2 - 2 * (vecs @ embed([text])[0]), 0))
    outbox.send(msgpack.packb(names[int(np.argmin(d))]))
"""
_RAW_DRIVER = """
import functools, os, shutil, subprocess, sys, tempfile, time, msgpack, zmq
from actors import die_with_parent
from embagents.bench.cases_memory import _RAW_MODEL, _RAW_ROUTER
folder = tempfile.mkdtemp(prefix="ea-raw-")
where = "ipc://" + folder
ctx = zmq.Context()
out, inp = ctx.socket(zmq.PULL), ctx.socket(zmq.PUSH)
out.bind(where + "/out")
orphan_guard = functools.partial(die_with_parent, os.getpid())  # the two go with this driver, even on SIGKILL
kids = [subprocess.Popen([sys.executable, "-c", _RAW_MODEL, sys.argv[1], where], preexec_fn=orphan_guard),
        subprocess.Popen([sys.executable, "-c", _RAW_ROUTER, where], preexec_fn=orphan_guard)]
inp.connect(where + "/in")
try:
    for line in sys.stdin:
        t0 = time.monotonic()
        inp.send(msgpack.packb(line.strip()))
        route = msgpack.unpackb(out.recv())
        print(time.monotonic() - t0, route, flush=True)
finally:
    for k in kids:
        k.kill()
        k.wait()
    ctx.destroy(linger=0)
    shutil.rmtree(folder, ignore_errors=True)  # the ipc socket files
"""


@case("router_latency", transport="embagents", kind="router", needs="onnxruntime")
def router_latency(opts: BenchOptions) -> dict[str, Any]:
    folder = prepared_minilm()
    n = 6 if opts.quick else 120
    runtime: list[float] = []
    inproc: list[float] = []
    raw: list[float] = []
    agree = 0
    with Baseline(_BASELINE, folder, what="in-process router") as base, \
            Baseline(_RAW_DRIVER, folder, what="raw pyzmq router") as floor, ActorSystem() as asys:
        asys.spawn(ModelActor, "bench_minilm", "embedding", folder, {}, True, wait=120, heartbeat=None)
        asys.spawn(RouterHost, "bench_router", "bench_minilm", wait=60)
        got: queue.Queue[tuple[float, str]] = queue.Queue()

        def subscribe(name: str) -> Subscription:
            return Subscription(asys.rt, asys.loop, name, lambda msg: got.put((time.monotonic(), name)),
                                queue_size=100, keep="all")

        for name in ROUTES:
            asys.rt.on_client(partial(subscribe, name))
        pub = asys.rt.on_client(lambda: Publisher(asys.rt, "bench_heard"))

        def send(text: str, sent: list[float]) -> None:
            sent.append(time.monotonic())
            pub.publish(String(data=text))

        # Subscriptions connected, and the router's start-up client (it embedded the samples) no longer
        # counts as active: the model actor would hold a request up to batch_wait_ms for it.
        time.sleep(1.2)
        for i in range(n + 2):  # the first two of each are warm-ups; interleaved, so drifts hit both
            text = TEXTS[i % len(TEXTS)]
            sent: list[float] = []
            # Both ends are stamped on this process's IO thread: as the String goes out, as the routed one
            # arrives (the hand-offs to and from the bench's own thread are the harness, not the runtime).
            asys.rt.on_client(partial(send, text, sent))
            t1, ours = got.get(timeout=60)  # waited for, not polled
            t0 = sent[0]
            secs, theirs = base.ask(text).split()
            raw_secs, raw_route = floor.ask(text).split()
            if i >= 2:
                runtime.append(t1 - t0)
                inproc.append(float(secs))
                raw.append(float(raw_secs))
                agree += ours == theirs == raw_route
    ours_p50, base_p50, raw_p50 = statistics.median(runtime), statistics.median(inproc), statistics.median(raw)
    return {
        "p50_us": ours_p50 * 1e6,
        "p99_us": float(np.percentile(runtime, 99)) * 1e6,
        "msgs_per_s": 1.0 / ours_p50,
        "ratio": ours_p50 / base_p50,
        "inprocess_p50_us": base_p50 * 1e6,
        "pyzmq_p50_us": raw_p50 * 1e6,
        "pyzmq_ratio": raw_p50 / base_p50,
        "over_pyzmq_us": (ours_p50 - raw_p50) * 1e6,  # what the runtime adds over bare pyzmq, same topology
        "same_route": f"{agree}/{len(runtime)}",
        "note": f"all-MiniLM-L6-v2, 3 routes x 3 samples, {len(runtime)} texts; raw pyzmq, same 4 hops: "
                f"{raw_p50 / base_p50:.2f}x (ours {(ours_p50 - raw_p50) * 1e6:+.0f} us); "
                "bar: ratio <= 1.15",
    }


def _vectors(rng: np.random.Generator, n: int, centers: np.ndarray) -> np.ndarray:
    v = centers[rng.integers(0, len(centers), n)] + 0.7 * rng.standard_normal((n, centers.shape[1])).astype(np.float32)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _queries(store: Any, rng: np.random.Generator, centers: np.ndarray, n: int,
             every: np.ndarray) -> tuple[float, float, float]:
    """Semantic and radius p50 (ms) over ``n`` queries, and the semantic top-10's recall against exact search."""
    sem, rad, recall = [], [], []
    for q, (x, y) in zip(_vectors(rng, n, centers), rng.uniform(0, 100, (n, 2)), strict=True):
        t0 = time.perf_counter()
        found = store.semantic(q, k=10)
        t1 = time.perf_counter()
        store.within((x, y), 2.0, limit=10)
        sem.append(t1 - t0)
        rad.append(time.perf_counter() - t1)
        exact = set((np.argpartition(-(every @ q), 10)[:10] + 1).tolist())  # ids start at 1
        recall.append(len(exact & {h["id"] for h in found}) / 10)
    return statistics.median(sem) * 1e3, statistics.median(rad) * 1e3, float(np.mean(recall))


@case("memory_scale", transport="embagents", kind="memory", needs="apsw")
def memory_scale(opts: BenchOptions) -> dict[str, Any]:
    small, large, queries = (200, 2_000, 20) if opts.quick else (1_000, 100_000, 200)
    rng = np.random.default_rng(0)
    centers = rng.standard_normal((2000, 384)).astype(np.float32)
    with tempfile.TemporaryDirectory() as tmp:
        store = MemoryStore(os.path.join(tmp, "memory.db"), dim=384, model="bench")
        stored, store_s, batch = 0, 0.0, 500
        every = np.zeros((large, 384), np.float32)  # for the recall of the semantic queries
        at: dict[int, tuple[float, float, float]] = {}
        for target in (small, large):
            while stored < target:
                k = min(batch, target - stored)
                vecs, pos = _vectors(rng, k, centers), rng.uniform(0, 100, (k, 2))
                every[stored:stored + k] = vecs
                items = [("seen", f"item {stored + i}", vecs[i], (pos[i, 0], pos[i, 1], 0.0), None, None)
                         for i in range(k)]
                t0 = time.perf_counter()
                store.add_many(items)
                store_s += time.perf_counter() - t0
                stored += k
            at[target] = _queries(store, rng, centers, queries, every[:stored])
        size = os.path.getsize(os.path.join(tmp, "memory.db"))
        store.close()
    q_small, q_large = max(at[small][:2]), max(at[large][:2])
    return {
        "p50_us": q_large * 1e3,
        "p99_us": q_large * 1e3,
        "msgs_per_s": stored / store_s,
        "store_per_s": round(stored / store_s),
        "query_p50_ms_1k": round(q_small, 3),
        "query_p50_ms_100k": round(q_large, 3),
        "semantic_p50_ms": [round(at[small][0], 3), round(at[large][0], 3)],
        "radius_p50_ms": [round(at[small][1], 3), round(at[large][1], 3)],
        "growth": round(q_large / q_small, 2),
        "recall_at_10": [round(at[small][2], 3), round(at[large][2], 3)],
        "db_mb": round(size / 1e6, 1),
        "note": (f"{small:,} then {large:,} items (384-d, batches of {batch}), {queries} semantic top-10 + 2 m radius "
                 "(nearest 10) queries each; bar: query_p50_ms_100k <= 20 and < 10 x query_p50_ms_1k"),
    }


_SYSTEM = '''
from embagents import EmbeddingModel, LocalModelClient, MapLayer, Memory, MemoryConfig, Odometry, String, System, Topic

minilm = EmbeddingModel(name="bench_crash_minilm", local_model_path={model!r})
memory = Memory(name="bench_memory", position=Topic("odom", Odometry), embedding_client=LocalModelClient(minilm),
                layers=[MapLayer(subscribes_to=Topic("notes", String))], config=MemoryConfig(db_path={db!r}))
system = System([memory], models=[minilm])
'''


@case("memory_crash", transport="embagents", kind="memory", needs="apsw")
def memory_crash(opts: BenchOptions) -> dict[str, Any]:
    total, kill_at = (60, 20) if opts.quick else (600, 200)
    folder = prepared_minilm()
    acked: list[int] = []
    failed = 0
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "system.py")
        with open(path, "w", encoding="utf-8") as f:
            f.write(textwrap.dedent(_SYSTEM).format(model=folder, db=os.path.join(tmp, "memory.db")))
        remember_system(path, load_system(path))
        with ActorSystem() as asys:
            sup = start_supervisor(asys, SupervisorSpec(intensity=5, period=10, children=[
                ChildSpec("bench_crash_minilm", (ModelActor, ("embedding", folder, {}, True)), start_timeout=120),
                ChildSpec("bench_memory", (ComponentActor, (path, "bench_memory")), lifecycle="active"),
            ]))
            try:
                ref = asys.ref("bench_memory")
                killed = threading.Event()
                t_kill = [0.0]

                def killer() -> None:
                    while len(acked) < kill_at:
                        time.sleep(0.005)
                    pid = [c.pid for c in sup.which_children() if c.id == "bench_memory"][0]
                    assert isinstance(pid, int), f"bench_memory is not running: {pid!r}"
                    t_kill[0] = time.monotonic()
                    os.kill(pid, signal.SIGKILL)
                    killed.set()

                th = threading.Thread(target=killer, daemon=True)
                th.start()
                for i in range(total):
                    try:
                        acked.append(ref.ask(Call("remember", [f"note {i}"]), timeout=30).get())
                    except Exception:  # the ask the kill cut short: not acknowledged, may or may not be stored
                        failed += 1
                th.join(30)
                stored = ref.ask(Call("item_ids"), timeout=30).get()
            finally:
                sup.stop()
    lost = len(set(acked) - set(stored))
    return {
        "p50_us": 0.0,
        "p99_us": 0.0,
        "msgs_per_s": None,
        "lost": lost,
        "acked": len(acked),
        "stored": len(stored),
        "asks_failed": failed,
        "killed": killed.is_set(),
        "note": f"{total} remember asks, SIGKILL after {kill_at} acknowledged; bar: lost == 0",
    }
