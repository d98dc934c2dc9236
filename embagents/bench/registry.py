"""The registry of benchmark cases and the helpers every case uses.

A case is a function ``fn(opts) -> dict`` registered under a unique name
with its transport and payload size. It returns the measured numbers
(``p50_us``, ``p99_us``, ``msgs_per_s`` and any extra keys, e.g. ``note``);
:func:`run_case` adds the identifying keys and turns an exception into a
row with an ``error`` note, so one broken transport never hides the others.

Adding a case is one decorator::

    >>> from embagents.bench.registry import BenchOptions, case, run_case
    >>> @case("demo_noop", transport="embagents", payload_bytes=0, kind="demo")
    ... def demo(opts: BenchOptions) -> dict:
    ...     return {"p50_us": 1.0, "p99_us": 2.0, "msgs_per_s": None}
    >>> run_case(CASES["demo_noop"], BenchOptions(quick=True))["p50_us"]
    1.0
    >>> del CASES["demo_noop"]

Cases that need the same code at several sizes register one partial per
size (see :func:`sized`).
"""

from __future__ import annotations

import contextlib
import fnmatch
import functools
import importlib.util
import os
import subprocess
import sys
import time
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "CASES",
    "Baseline",
    "FRAME_1080P",
    "MIB",
    "SIZES",
    "TRANSPORTS",
    "BenchOptions",
    "Case",
    "Skipped",
    "case",
    "interleaved",
    "iterations",
    "label",
    "payload",
    "percentiles",
    "run_case",
    "run_rounds",
    "scoped_environ",
    "select",
    "shm_entries",
    "shm_leftovers",
    "shm_mapped",
    "sized",
    "stop_process",
]

TRANSPORTS = ("embagents", "pyzmq", "mp_queue", "rclpy")
MIB = 1 << 20
#: A 1080p RGB uint8 frame.
FRAME_1080P = 1920 * 1080 * 3
#: The payload sizes every transport is measured at.
SIZES = (64, MIB, FRAME_1080P)

_LABELS = {64: "64B", MIB: "1MiB", FRAME_1080P: "6.2MB"}


def label(size: int) -> str:
    """Short size label used in case names.

    >>> label(64), label(1 << 20), label(6_220_800)
    ('64B', '1MiB', '6.2MB')
    """
    return _LABELS.get(size, f"{size}B")


@dataclass(frozen=True)
class BenchOptions:
    """How hard to measure. ``quick`` runs few iterations (tests, smoke runs).

    >>> BenchOptions(quick=True).idle_seconds
    2.0
    """

    quick: bool = False
    #: How long the ``chaos`` case injects faults (None: 1 minute, 0.1 with ``quick``).
    minutes: float | None = None
    #: A tag unique to this run (socket paths, ROS topic names).
    tag: str = field(default_factory=lambda: f"{os.getpid()}{time.monotonic_ns() % 100000}")

    @property
    def idle_seconds(self) -> float:
        return 2.0 if self.quick else 10.0


# Round trips measured (after warm-up) per payload size, full / quick.
_ITERS: dict[str, dict[int, tuple[int, int]]] = {
    "default": {64: (2000, 200), MIB: (300, 30), FRAME_1080P: (100, 15)},
    "rclpy": {64: (1000, 100), MIB: (100, 10), FRAME_1080P: (40, 5)},
    "topic": {64: (2000, 200), MIB: (300, 30), FRAME_1080P: (100, 15)},
}


def iterations(size: int, opts: BenchOptions, family: str = "default") -> tuple[int, int]:
    """``(warmup, measured)`` iteration counts for ``size``.

    >>> iterations(64, BenchOptions())
    (200, 2000)
    """
    full, quick = _ITERS[family].get(size, (100, 10))
    n = quick if opts.quick else full
    return max(5, n // 10), n


def payload(size: int) -> bytes | np.ndarray:
    """The payload of ``size`` bytes: ``bytes`` below 64 KB, else a uint8 array.

    >>> type(payload(64)).__name__, payload(1 << 20).dtype.name
    ('bytes', 'uint8')
    """
    if size < 64 * 1024:
        return bytes(range(256)) * (size // 256) + bytes(size % 256)
    arr: np.ndarray
    if size == FRAME_1080P:
        arr = np.empty((1080, 1920, 3), dtype=np.uint8)
    else:
        arr = np.empty(size, dtype=np.uint8)
    arr.reshape(-1)[:] = np.arange(size, dtype=np.uint8)
    return arr


def percentiles(samples_ns: Any) -> dict[str, float]:
    """p50 / p99 in microseconds of latencies given in nanoseconds.

    >>> percentiles([1000, 2000, 3000])["p50_us"]
    2.0
    """
    arr = np.asarray(samples_ns, dtype=np.float64)
    if arr.size == 0:
        raise RuntimeError("no samples were measured")
    p50, p99 = np.percentile(arr, [50, 99]) / 1000.0
    return {"p50_us": round(float(p50), 2), "p99_us": round(float(p99), 2)}


@dataclass(frozen=True)
class Case:
    """One row of the benchmark: ``fn(opts)`` measures it."""

    name: str
    transport: str
    payload_bytes: int
    kind: str
    fn: Callable[[BenchOptions], dict[str, Any]]
    needs: str | None = None  # module that must be importable, else the case is skipped


#: Every registered case by name, in registration order (that is the run order).
CASES: dict[str, Case] = {}


def case(
    name: str, *, transport: str, payload_bytes: int = 0, kind: str, needs: str | None = None
) -> Callable[[Callable[[BenchOptions], dict[str, Any]]], Callable[[BenchOptions], dict[str, Any]]]:
    """Decorator: register ``fn`` as case ``name``."""

    def deco(fn: Callable[[BenchOptions], dict[str, Any]]) -> Callable[[BenchOptions], dict[str, Any]]:
        add(Case(name, transport, payload_bytes, kind, fn, needs))
        return fn

    return deco


def add(c: Case) -> None:
    """Register ``c``; names are unique."""
    if c.transport not in TRANSPORTS:
        raise ValueError(f"case {c.name!r}: transport must be one of {TRANSPORTS}, not {c.transport!r}")
    if c.name in CASES:
        raise ValueError(f"a benchmark case named {c.name!r} is already registered")
    CASES[c.name] = c


def sized(
    kind: str, transport: str, fn: Callable[[int, BenchOptions], dict[str, Any]], *,
    sizes: tuple[int, ...] = SIZES, needs: str | None = None,
) -> None:
    """Register ``fn(size, opts)`` once per size as ``<transport>_<kind>_<label>``.

    >>> sized("demo", "pyzmq", lambda size, opts: {"p50_us": 0.0, "p99_us": 0.0, "msgs_per_s": None}, sizes=(64,))
    >>> sorted(n for n in CASES if n.startswith("pyzmq_demo"))
    ['pyzmq_demo_64B']
    >>> del CASES["pyzmq_demo_64B"]
    """
    for size in sizes:
        add(Case(f"{transport}_{kind}_{label(size)}", transport, size, kind, functools.partial(fn, size), needs))


#: Fresh starts per transport for the interleaved cases (see :func:`interleaved`).
ROUNDS = 3


def interleaved(c: Case) -> bool:
    """Whether ``c`` runs in round-robin rounds with the other transports' same case.

    A 64 B round trip is ~0.1 ms: where the scheduler puts the two processes
    on 2 cores moves it by +-30 % from one start to the next, and a shared
    virtual machine's speed drifts by as much from one minute to the next.
    So the 64 B asks of every transport run round robin, ``ROUNDS`` fresh
    starts each, and each reports its median start: the two sides of a
    ratio are measured in the same minute.

    >>> interleaved(Case("x", "pyzmq", 64, "ask", lambda o: {})), interleaved(Case("y", "pyzmq", MIB, "ask", lambda o: {}))
    (True, False)
    """
    return c.kind == "ask" and c.payload_bytes == 64


def run_rounds(cases: list[Case], opts: BenchOptions, log: Callable[[str], None] = print) -> dict[str, dict[str, Any]]:
    """Run ``cases`` round robin, ``ROUNDS`` times; return each case's row of its median start.

    A case that errs or is skipped in any round reports that round's row.
    """
    runs: dict[str, list[dict[str, Any]]] = {c.name: [] for c in cases}
    for r in range(ROUNDS):
        for c in cases:
            if runs[c.name] and runs[c.name][-1]["status"] != "ok":
                continue
            row = run_case(c, opts)
            runs[c.name].append(row)
            log(f"bench: {c.name} round {r + 1}/{ROUNDS}: " + (f"p50 {row['p50_us']:.1f} us" if row["status"] == "ok" else row["status"]))
    out = {}
    for name, rows in runs.items():
        bad = [row for row in rows if row["status"] != "ok"]
        if bad:
            out[name] = bad[0]
            continue
        rows.sort(key=lambda row: row["p50_us"])
        best = dict(rows[len(rows) // 2])
        best["runs_p50_us"] = [row["p50_us"] for row in rows]
        best["seconds"] = round(sum(row["seconds"] for row in rows), 2)
        out[name] = best
    return out


def select(only: list[str] | None) -> list[Case]:
    """The cases to run, in run order: all, or those matching any of ``only``.

    A pattern matches a case name exactly, as a glob (``"*ask*"``), as a
    substring of the name, or names a transport or kind. Cases run grouped
    by transport in :data:`TRANSPORTS` order (ours first), each group in
    registration order.
    """
    if not only:
        return sorted(CASES.values(), key=lambda c: TRANSPORTS.index(c.transport))
    out = []
    for c in CASES.values():
        for pat in only:
            if (
                fnmatch.fnmatchcase(c.name, pat)
                or pat in c.name
                or pat in (c.transport, c.kind)
            ):
                out.append(c)
                break
    if not out:
        raise ValueError(f"no benchmark case matches {only}; cases: {', '.join(CASES)}")
    return sorted(out, key=lambda c: TRANSPORTS.index(c.transport))


@contextlib.contextmanager
def scoped_environ(values: dict[str, str]) -> Iterator[None]:
    """Set environment variables for the block (the actor processes it starts inherit them), then restore them."""
    saved = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


class Skipped(Exception):
    """Raised by a case that cannot run here (no GPU, say); its message is the row's note."""


def run_case(c: Case, opts: BenchOptions) -> dict[str, Any]:
    """Run one case and return its row.

    ``row["status"]`` is ``"ok"``, ``"skipped"`` (``needs`` is not installed,
    or the case raised :class:`Skipped`; ``note`` says why) or ``"error"``
    (``error`` holds the exception).
    """
    row: dict[str, Any] = {
        "name": c.name,
        "transport": c.transport,
        "kind": c.kind,
        "payload_bytes": int(c.payload_bytes),
    }
    if c.needs is not None and importlib.util.find_spec(c.needs) is None:
        row.update(status="skipped", note=f"skipped: {c.needs} is not installed")
        return row
    t0 = time.monotonic()
    try:
        res = c.fn(opts)
    except Skipped as exc:
        row.update(status="skipped", note=f"skipped: {exc}")
        return row
    except Exception as exc:
        row.update(status="error", error=f"{type(exc).__name__}: {exc}", traceback=traceback.format_exc())
        return row
    row.update(res)
    row.setdefault("msgs_per_s", None)
    row["status"] = "ok"
    row["seconds"] = round(time.monotonic() - t0, 2)
    return row


def stop_process(proc: subprocess.Popen, grace: float = 3.0) -> int | None:
    """Wait ``grace`` seconds for ``proc`` to exit, then SIGTERM, then SIGKILL; return its code.

    >>> stop_process(subprocess.Popen(["true"]))
    0
    """
    for step in (None, proc.terminate, proc.kill):
        if step is not None:
            with contextlib.suppress(ProcessLookupError):
                step()
        try:
            return proc.wait(grace)
        except subprocess.TimeoutExpired:
            continue
    return proc.wait()


class Baseline:
    """An in-process baseline in a process of its own, asked a line at a time.

    ``python -c script *args`` reads a line on stdin per round and answers one
    line on stdout. Baselines that load onnxruntime (or any library with thread
    pools) must not run in the bench's own process: its later ActorSystems fork
    their fork server from it, and those pools do not survive a fork.

    >>> with Baseline("import sys\\nfor line in sys.stdin: print(line.strip().upper(), flush=True)") as b:
    ...     b.ask("hello")
    'HELLO'
    """

    def __init__(self, script: str, *args: str, what: str = "in-process baseline") -> None:
        self.argv, self.what = [sys.executable, "-c", script, *args], what

    def __enter__(self) -> Baseline:
        self.proc = subprocess.Popen(self.argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        return self

    def ask(self, line: str = "") -> str:
        """Send ``line``; its answer line (without the newline)."""
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        answer = self.proc.stdout.readline()
        if not answer:
            raise RuntimeError(f"the {self.what} ended (exit {self.proc.poll()}); see its stderr above")
        return answer.rstrip("\n")

    def __exit__(self, *exc: object) -> None:
        if self.proc.stdin is not None:
            self.proc.stdin.close()  # its loop ends
        stop_process(self.proc)
        if self.proc.stdout is not None:
            self.proc.stdout.close()


#: What this run's processes put in /dev/shm: name prefixes (one per ActorSystem)
#: and exact names (segments the rclpy peers mapped). Checked after the run.
OWNED_SHM_PREFIXES: set[str] = set()
OWNED_SHM_NAMES: set[str] = set()


def shm_entries() -> set[str]:
    """Names in ``/dev/shm`` now."""
    with contextlib.suppress(FileNotFoundError):
        return set(os.listdir("/dev/shm"))
    return set()


def shm_mapped(pid: int | str = "self") -> set[str]:
    """Names of the ``/dev/shm`` files process ``pid`` has mapped (empty if it is gone).

    >>> isinstance(shm_mapped(), set)
    True
    """
    try:
        with open(f"/proc/{pid}/maps") as f:
            return {line.split("/dev/shm/", 1)[1].strip() for line in f if "/dev/shm/" in line}
    except OSError:
        return set()


def shm_leftovers(before: set[str] | frozenset[str] = frozenset()) -> list[str]:
    """Entries this run created (absent from ``before``), still in /dev/shm, that no live process maps."""
    now = shm_entries() - before
    suspects = {n for n in now if n.startswith(tuple(OWNED_SHM_PREFIXES))} if OWNED_SHM_PREFIXES else set()
    suspects |= OWNED_SHM_NAMES & now
    if not suspects:
        return []
    in_use: set[str] = set()
    for pid in os.listdir("/proc"):
        if pid.isdigit():
            in_use |= shm_mapped(pid) & suspects
    return sorted(suspects - in_use)
