"""What the root of ``embagents supervise`` serves for the tools: topics and recorders.

:func:`install` adds control commands (see :mod:`supervisor.control`):

- ``{"cmd": "topics"}`` -> ``{"ok", "topics": [{name, type, wire, keep, queue_size,
  publishers, subscribers, rate}]}``: the declared topics (and the runtime's
  own, such as ``_supervisor.events``); ``rate`` is messages/s, measured from
  the subscribers' counters (``None`` when nobody subscribes); with
  ``"rates": false`` the rows come at once, every ``rate`` ``None``.
- ``{"cmd": "record_start", "path", "topics", "max_bytes", "max_seconds",
  "max_files", "compression", "chunk_bytes", "overwrite"}`` -> starts a
  :class:`~embagents.tools.recorder.RecorderActor` child of the root
  (``{"ok", "name", "path"}``); refused for an unknown topic, a file being
  recorded, or an existing file without ``overwrite``.
- ``{"cmd": "record_stop", "path"}`` -> stops that recorder (its files are
  finished) and answers ``{"ok", "files"}``.
- ``{"cmd": "voice_stages"}`` -> ``{"ok", "topics", "turns", "latest", "p50"}``:
  the voice turns heard on the system's :class:`~embagents.msgs.VoiceStage`
  topics (:class:`~embagents.components.voice_stages.VoiceTurns`; ``topics``
  empty when it has none), what ``embagents status`` shows under its table.

Example::

    install(sup, control, system)      # in embagents.cli.supervise's on_ready
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from typing import TYPE_CHECKING, Any

from actors.codec import message_name
from actors.topics import Subscription, topic_dir
from embagents.components.voice_stages import VoiceTurns
from embagents.msgs import VoiceStage
from embagents.tools.recorder import RecorderActor, rotation_files
from supervisor import ChildSpec

if TYPE_CHECKING:  # for the annotation only: embagents.system imports most of the package
    from embagents.system import System

__all__ = ["EVENTS_TOPIC", "install", "topic_rows", "voice_lines"]

#: The supervisor's events topic (dicts; see supervisor.events).
EVENTS_TOPIC = "_supervisor.events"


def _marks(run_dir: str, name: str) -> int:
    try:
        return sum(1 for f in os.listdir(topic_dir(run_dir, name.replace("/", "."))) if not f.startswith("."))
    except FileNotFoundError:
        return 0


def _received(rows: list[dict[str, Any]]) -> dict[str, int]:
    """Per topic (dotted name), the most messages one subscription received."""
    out: dict[str, int] = {}
    for r in rows:
        for s in r.get("subscriptions") or []:
            out[s["topic"]] = max(out.get(s["topic"], 0), s["received"])
    return out


def topic_rows(system: System, run_dir: str) -> list[dict[str, Any]]:
    """The topics of ``system`` (and the runtime's own under ``run_dir``), without rates."""
    rows: dict[str, dict[str, Any]] = {}
    for name, t in sorted(system.topics.items()):
        pubs = sorted(str(c.name) for c in system.components if any(o.name == name for o in c.outputs))
        if any(x.name == name for x in getattr(system, "external", []) or []):
            pubs.append("(external)")
        rows[name] = {"name": name, "type": t.type_name, "wire": message_name(t.msg_type), "keep": t.keep,
                      "queue_size": t.queue_size, "publishers": pubs}
    bridge = getattr(system, "zenoh", None)  # a ZenohBridge: remote topics name their host's key
    for i in getattr(bridge, "imports", ()):
        if i.topic in rows:
            rows[i.topic]["publishers"].append(f"(remote {i.key})")
            rows[i.topic]["remote"] = i.key
    for e in getattr(bridge, "exports", ()):
        if bridge is not None and e.topic in rows:
            rows[e.topic]["exported"] = bridge.key_of(e)
    rows.setdefault(EVENTS_TOPIC, {"name": EVENTS_TOPIC, "type": "SupervisorEvent", "wire": "", "keep": "latest",
                                   "queue_size": 100, "publishers": ["(supervisor)"]})
    for r in rows.values():
        r["subscribers"] = _marks(run_dir, r["name"])
    return list(rows.values())


class _Topics:
    """``topics``: rows with rates from two looks at the subscribers' counters."""

    def __init__(self, control: Any, system: System) -> None:
        self.control, self.system = control, system
        self.prev: tuple[float, dict[str, int]] | None = None
        self.lock = threading.Lock()  # requests run side by side: one look at the counters at a time

    def __call__(self, req: dict[str, Any]) -> dict[str, Any]:
        if req.get("rates") is False:  # a client checking a name: no half-second look at the rates
            return {"ok": True, "topics": [{**r, "rate": None} for r in topic_rows(self.system, self.control.system.run_dir)]}
        rows = self.control.rows()
        if self.prev is None or time.monotonic() - self.prev[0] > 10:  # no recent look: take one now
            self.table(rows)
            time.sleep(0.5)
            rows = self.control.rows()
        return {"ok": True, "topics": self.table(rows)}

    def table(self, status_rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
        """The topic rows, rates since the previous call (from ``status_rows``' subscription counters)."""
        with self.lock:
            now, counts = time.monotonic(), _received(status_rows)
            then, before = self.prev or (now, {})
            self.prev = (now, counts)
        rows = topic_rows(self.system, self.control.system.run_dir)
        for r in rows:
            key = r["name"].replace("/", ".")
            n, n0 = counts.get(key), before.get(key)
            ok = n is not None and n0 is not None and n >= n0 and now > then
            r["rate"] = round((n - n0) / (now - then), 1) if ok else None  # type: ignore[operator]
        return rows


class _Recorders:
    """``record_start`` / ``record_stop``: recorder children of the root."""

    def __init__(self, sup: Any, control: Any, system: System) -> None:
        self.sup, self.control, self.system = sup, control, system
        self.active: dict[str, str] = {}  # path -> child name
        self.lock = threading.Lock()
        self.seq = 0

    def start(self, req: dict[str, Any]) -> dict[str, Any]:
        path = req.get("path")
        if not isinstance(path, str) or not os.path.isabs(path) or not path.endswith(".mcap"):
            return {"ok": False, "error": f"record needs an absolute path ending in .mcap, got {path!r}"}
        rows = {r["name"]: r for r in topic_rows(self.system, self.control.system.run_dir)}
        wanted = req.get("topics") or list(rows)
        unknown = [t for t in wanted if t not in rows]
        if unknown:
            return {"ok": False, "error": f"no topic {', '.join(map(repr, unknown))} in system {self.system.name!r}; "
                    f"its topics: {', '.join(rows)}"}
        with self.lock:
            if path in self.active:
                return {"ok": False, "error": f"{path} is already being recorded (by {self.active[path]}); "
                        f"stop it with `embagents record --stop {path}` or record to another file"}
            if rotation_files(path) and not req.get("overwrite"):
                return {"ok": False, "error": f"{path} exists; pass --overwrite to replace it or choose another -o"}
            for old in rotation_files(path):
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(old)
            self.seq += 1
            name = f"_record.{self.seq}"
            topics = [[t, rows[t]["wire"], rows[t]["keep"], rows[t]["queue_size"]] for t in wanted]
            limits = {k: req.get(k) for k in ("max_bytes", "max_seconds", "max_files", "compression", "chunk_bytes")}
            self.active[path] = name
        try:
            self.sup.start_child(ChildSpec(name, (RecorderActor, (path, topics, limits)), shutdown=10.0))
        except Exception as exc:
            with self.lock:
                self.active.pop(path, None)
            return {"ok": False, "error": f"the recorder did not start: {exc}"}
        return {"ok": True, "name": name, "path": path, "topics": wanted}

    def stop(self, req: dict[str, Any]) -> dict[str, Any]:
        path = req.get("path")
        with self.lock:
            name = self.active.pop(path, None) if isinstance(path, str) else None
        if name is None:
            return {"ok": False, "error": f"nothing is recording to {path!r}; recording now: "
                    f"{', '.join(self.active) or 'nothing'}"}
        self.sup.terminate_child(name)
        self.sup.delete_child(name)
        return {"ok": True, "files": rotation_files(str(path))}


class _VoiceStages:
    """``voice_stages``: the turns of the system's VoiceStage topics, from subscriptions in the root."""

    def __init__(self, sup: Any, system: System) -> None:
        topics = {n: t for n, t in system.topics.items() if t.msg_type is VoiceStage}
        self.names = sorted(topics)
        self.turns = {n: VoiceTurns() for n in self.names}
        self.lock = threading.Lock()  # fed on the root's IO thread, read on a control thread
        asys = sup.system
        for name, t in topics.items():
            asys.rt.on_client(lambda name=name, t=t: Subscription(
                asys.rt, asys.loop, name, self._feeder(name), queue_size=t.queue_size, keep=t.keep,
                msg_type=VoiceStage))

    def _feeder(self, name: str) -> Any:
        def feed(msg: Any) -> None:
            with self.lock:
                self.turns[name].feed(msg)

        return feed

    def __call__(self, req: dict[str, Any]) -> dict[str, Any]:
        with self.lock:
            found = {n: self.turns[n].summary() for n in self.names}
        best = max(found.values(), key=lambda s: s["turns"], default={"turns": 0, "latest": {}, "p50": {}})
        return {"ok": True, "topics": self.names, **best}


def voice_lines(reply: dict[str, Any]) -> list[str]:
    """``embagents status``'s lines on the voice stages of a ``voice_stages`` reply (none before a turn)."""
    if not reply.get("turns"):
        return []

    def cell(v: Any) -> str:
        return "-" if v is None else f"{v:.0f} ms"

    names = list(reply["p50"])
    widths = [max(len(n), 8) + 2 for n in names]
    lines = [f"voice stages ({reply['turns']} turn{'s' if reply['turns'] != 1 else ''}, on {', '.join(reply['topics'])}):",
             "  " + f"{'':8}" + "".join(f"{n:>{w}}" for n, w in zip(names, widths, strict=True))]
    for label in ("latest", "p50"):
        lines.append("  " + f"{label:8}" + "".join(f"{cell(reply[label].get(n)):>{w}}"
                                                   for n, w in zip(names, widths, strict=True)))
    return lines


def install(sup: Any, control: Any, system: System) -> _Topics:
    """Serve ``topics``, ``record_start``, ``record_stop`` and ``voice_stages`` on ``control`` for ``system``;
    returns the topics table."""
    control.add_command("voice_stages", _VoiceStages(sup, system))
    topics = _Topics(control, system)
    control.add_command("topics", topics)
    recorders = _Recorders(sup, control, system)
    control.add_command("record_start", recorders.start)
    control.add_command("record_stop", recorders.stop)
    return topics
