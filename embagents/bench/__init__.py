"""``embagents bench``: our runtime side by side with raw pyzmq, multiprocessing queues and rclpy.

Cases (each a row of the report and of the JSON file):

* ``<transport>_ask_<size>``: round trips between two processes at 64 B,
  1 MiB and 6,220,800 B (a 1080p RGB frame) over our actors (an actor
  process asks another from inside its handler), raw pyzmq DEALER/ROUTER,
  ``multiprocessing.Queue`` and rclpy ping-pong (if rclpy is installed).
* ``<transport>_topic_<size>``: one-way publish -> subscriber latency
  (our topics and raw PUB/SUB), from a CLOCK_MONOTONIC stamp in the message.
* ``<transport>_tell_64B``: pipelined 64-byte tells, messages per second.
* ``idle_10_actors``: ten idle actors' CPU, % of one core.
* ``remote_model``: the LLM stream and a 640x480 detection through a model
  actor on loopback TCP with CURVE against the same actor over ipc
  (:mod:`embagents.bench.cases_remote`).
* ``chaos``: the chat system and two streams under the supervisor while a
  fault injector kills, hangs, bloats or breaks a random actor every few
  seconds (``minutes``: 1 by default, 0.1 with ``quick``; see
  :mod:`embagents.bench.cases_chaos`).

The printed report ends with the side-by-side ratios and a PASS/FAIL
table for the project's bars. A run takes about a minute (under 3 on 2
cores); ``quick`` takes a few seconds per case family and is a smoke test
(every case runs, nothing is graded: its few iterations are noise).

New cases register themselves with :func:`embagents.bench.registry.case`
(import the module below so it is part of every run).

Example::

    >>> from embagents.bench import run_bench
    >>> doc = run_bench("bench.json", quick=True, only=["ask_64B"])   # doctest: +SKIP
    >>> [c["name"] for c in doc["cases"]]                             # doctest: +SKIP
    ['embagents_ask_64B', 'pyzmq_ask_64B', 'mp_queue_ask_64B', 'rclpy_ask_64B']

From the shell: ``python -m embagents.bench --json bench.json`` (or
``embagents bench --json bench.json``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from typing import Any

# Importing a case module registers its cases. The 64 B asks of every transport run
# first, round robin (see registry.interleaved); the rest run grouped by transport, ours
# first. Each ActorSystem forks its fork server from this process, which holds no
# sockets or threads between cases: every case closes its contexts and joins its threads.
from embagents.bench import (  # noqa: F401 - importing a case module registers its cases
    cases_actors,
    cases_arm,
    cases_chaos,
    cases_gpu,
    cases_llm,
    cases_manager,
    cases_memory,
    cases_mpqueue,
    cases_policy,
    cases_pyzmq,
    cases_rclpy,
    cases_remote,
    cases_ros_bridge,
    cases_ros_generic,
    cases_ros_recovery,
    cases_ros_service,
    cases_speech,
    cases_supervisor,
    cases_tools,
    cases_vision,
    cases_voice,
    cases_voice_turns,
    cases_zenoh,
    idle,
)
from embagents.bench.registry import (
    CASES,
    OWNED_SHM_NAMES,
    OWNED_SHM_PREFIXES,
    BenchOptions,
    case,
    interleaved,
    run_case,
    run_rounds,
    select,
    shm_entries,
    shm_leftovers,
)
from embagents.bench.report import annotate, evaluate, format_report

__all__ = ["CASES", "case", "run", "run_bench"]

_ROW_DROP = ("status", "traceback")


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def run_bench(
    json_path: str | None = None, *, quick: bool = False, only: list[str] | None = None, minutes: float | None = None,
) -> dict:
    """Run the selected cases, print the report, optionally write ``json_path``; return the document.

    ``only`` selects cases by name, glob, substring, transport or kind
    (``["ask"]``, ``["rclpy"]``, ``["embagents_ask_64B", "idle*"]``).
    The document is ``{"cases": [{"name", "transport", "payload_bytes",
    "p50_us", "p99_us", "msgs_per_s", ...}], "bars": [...], "skipped": [...],
    "errors": [...], ...}``; skipped and failed cases are not in ``cases``.
    """
    if minutes is not None and not minutes > 0:
        raise ValueError(f"--minutes must be a positive number of minutes, not {minutes}; e.g. --minutes 5")
    opts = BenchOptions(quick=quick, minutes=minutes)
    chosen = select(only)
    OWNED_SHM_PREFIXES.clear()
    OWNED_SHM_NAMES.clear()
    before = shm_entries()
    load0 = [round(x, 2) for x in os.getloadavg()]
    t0 = time.monotonic()
    rows, skipped, errors = [], [], []
    paired = [c for c in chosen if interleaved(c)] if not quick else []
    done = run_rounds(paired, opts, _log) if paired else {}
    for c in chosen:
        row = done.get(c.name)
        if row is None:
            _log(f"bench: {c.name} ...")
            row = run_case(c, opts)
        status = row.get("status")
        if status == "ok":
            rows.append({k: v for k, v in row.items() if k not in _ROW_DROP})
            _log(f"bench: {c.name}: p50 {row['p50_us']:.1f} us, p99 {row['p99_us']:.1f} us ({row['seconds']:.1f} s)")
        elif status == "skipped":
            skipped.append({"name": c.name, "transport": c.transport, "note": row["note"]})
            _log(f"bench: {c.name}: {row['note']}")
        else:
            errors.append({"name": c.name, "transport": c.transport, "error": row["error"]})
            _log(f"bench: {c.name} FAILED: {row['error']}\n{row.get('traceback', '')}")
    wall = time.monotonic() - t0
    time.sleep(0.2)  # let exiting peers finish their own clean-up
    leftovers = shm_leftovers(before)
    annotate(rows)
    doc: dict[str, Any] = {
        "cases": rows,
        "bars": evaluate(rows, grade=not quick),  # a quick run is a smoke test: no verdicts
        "skipped": skipped,
        "errors": errors,
        "shm_leftovers": leftovers,
        "quick": quick,
        "wall_s": round(wall, 1),
        "host": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "platform": platform.platform(),
            "loadavg_start": load0,
            "loadavg_end": [round(x, 2) for x in os.getloadavg()],
        },
    }
    print(format_report(doc), flush=True)
    if json_path:
        with open(json_path, "w") as f:
            json.dump(doc, f, indent=1)
            f.write("\n")
    return doc


def run(args: argparse.Namespace) -> int:
    """Run ``embagents bench`` with parsed ``args``; 0 = ran, 1 = a case failed, 2 = a bar failed (--strict)."""
    if getattr(args, "list", False):
        for c in select(None):
            print(f"{c.name:28s} {c.transport:10s} {c.kind:6s} {c.payload_bytes:>9,} B")
        return 0
    try:
        doc = run_bench(args.json, quick=args.quick, only=args.only, minutes=getattr(args, "minutes", None))
    except ValueError as exc:  # --only matched nothing, or a bad --minutes
        print(f"embagents bench: {exc}", file=sys.stderr)
        return 1
    if doc["errors"]:
        return 1
    if getattr(args, "strict", False) and any(b["pass"] is False for b in doc["bars"]):
        return 2
    return 0
