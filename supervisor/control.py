"""The root's control endpoint, and the discovery file a CLI finds it by.

A ROUTER socket at ``ipc://{run_dir}/_control`` (the run directory is 0700,
so only its user can connect) serves msgpack requests, one dict each, and
answers one dict each (``ok`` true or false, ``error`` text when false):

- ``{"cmd": "status"}`` -> ``{"ok", "system", "run_id", "pid", "uptime", "rows"}``,
  one row per child: name, supervisor (path), kind, restart, status
  (starting/running/restarting/stopped), lifecycle, pid, restarts, uptime
  (s), cpu_percent, rss_mb, mailbox (depth), handled, rate (messages/s since
  the previous status request, or since the start), last_exit, drops (messages
  its topic subscriptions lost), subscriptions (per subscription: topic, keep,
  queue_size, received, dropped, bad), stalled (per topic it publishes: the
  keep-all subscribers it is dropping for).
- ``{"cmd": "restart", "name": NAME}`` -> stop the child and start it again
  now (``Supervisor.bounce``); ``{"ok", "pid"}``.
- ``{"cmd": "stop"}`` -> answers, then stops the run cleanly (children in
  reverse order).
- ``{"cmd": "wait_ready"}`` -> ``{"ok", "ready": true}``, answered once the run
  is ready (at once if it is): a blocking request, no polling. The run is
  ready when the layer above says so (:meth:`ControlServer.mark_ready`), or,
  unless it :meth:`~ControlServer.hold_ready`, once the tree has started.
  ``status`` answers ``ready`` too.
- any command the layer above adds with :meth:`ControlServer.add_command`
  (``embagents supervise`` adds ``publish``: a message on a topic of the system).

While the endpoint is up, ``<private>/runs/<run_id>.json`` (``<private>`` is
:func:`actors.private_dir`: ``$XDG_RUNTIME_DIR/embagents`` or
``/tmp/embagents-<uid>``, checked at every use; ``$EMBAGENTS_RUNS_DIR`` (``$<APP>_RUNS_DIR``, :mod:`actors.app`)
overrides the folder, checked the same way) holds ``run_id``,
``run_dir``, ``pid``, ``system`` (the system's name), ``endpoint``,
``started`` and ``ready`` (rewritten when the run becomes ready); it is removed on close.

Example::

    control = ControlServer(system, "demo", on_stop=stop_event.set)
    from supervisor.client import request
    request(system.run_dir, {"cmd": "status"})["rows"][0]["name"]    # 'camera'
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import tempfile
import threading
import time
from collections.abc import Callable
from typing import Any

import msgpack
import pykka
import zmq

from actors import ActorRef, ActorSystem, check_folder, private_dir
from actors.app import env
from supervisor.rootio import on_root
from supervisor.tree import Tree

__all__ = ["ControlServer", "control_endpoint", "runs_dir"]

log = logging.getLogger("supervisor.control")


def runs_dir() -> str:
    """Where live runs announce themselves (0700; :class:`actors.UnsafeFolder` if it is not private)."""
    override = env("RUNS_DIR")
    return check_folder(override) if override else private_dir("runs")


def control_endpoint(run_dir: str) -> str:
    return f"ipc://{run_dir}/_control"


def _ctrl_async(name: str, cmd: str, timeout: float) -> pykka.Future:
    # ActorSystem.ctrl() blocks per call; one future per actor lets a status
    # request ask all of them at once (a hung actor costs one timeout, not one each).
    return ActorRef(name).control(cmd, timeout=timeout)


class ControlServer:
    """Serves control requests on its own thread; writes and removes the discovery file."""

    def __init__(
        self,
        system: ActorSystem,
        name: str,
        *,
        on_stop: Callable[[], None] | None = None,
        stats_timeout: float = 0.5,
    ) -> None:
        self.system = system
        self.name = name
        self.tree = Tree.of(system)
        self.on_stop = on_stop
        self.stats_timeout = stats_timeout
        self.started = time.time()
        self._t0 = time.monotonic()
        self._prev: dict[str, tuple[int, int, float]] = {}  # name -> (incarnation, handled, when)
        self._closed = threading.Event()
        self._commands: dict[str, Callable[[dict[str, Any]], dict[str, Any]]] = {}
        self.ready = False
        self.ready_held = False
        self._waiting: list[bytes] = []  # idents of wait_ready requests not answered yet (control thread only)
        self._wake_r, self._wake_w = os.pipe()  # mark_ready wakes the control thread to answer them
        self.endpoint = control_endpoint(system.run_dir)
        self.sock = system.rt.ctx.socket(zmq.ROUTER)
        self.sock.setsockopt(zmq.LINGER, 200)
        self.sock.bind(self.endpoint)
        self._thread = threading.Thread(target=self._serve, name="supervisor-control", daemon=True)
        self._thread.start()
        self.discovery = os.path.join(runs_dir(), f"{system.run_id}.json")
        self._announce()

    def _announce(self) -> None:
        info = {
            "run_id": self.system.run_id,
            "run_dir": self.system.run_dir,
            "pid": os.getpid(),
            "system": self.name,
            "endpoint": self.endpoint,
            "started": self.started,
            "ready": self.ready,
        }
        fd, tmp = tempfile.mkstemp(prefix=".announce-", dir=runs_dir())  # a reader never sees half a file
        with os.fdopen(fd, "w") as f:
            json.dump(info, f)
        os.replace(tmp, self.discovery)

    def hold_ready(self) -> None:
        """The layer above says when the run is ready (:meth:`mark_ready`); call it before :func:`~supervisor.run.serve` would."""
        self.ready_held = True

    def mark_ready(self) -> None:
        """The run is ready: answer the ``wait_ready`` requests and say so in the announcement (any thread)."""
        if self.ready:
            return
        self.ready = True
        with contextlib.suppress(OSError):
            self._announce()
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"r")

    # -- serving (its own thread: a status request may wait on actors) -------
    def _answer_waiting(self) -> None:
        with contextlib.suppress(OSError):
            os.read(self._wake_r, 64)
        if not self.ready:
            return
        waiting, self._waiting = self._waiting, []
        for ident in waiting:
            with contextlib.suppress(zmq.ZMQError):
                self.sock.send_multipart([ident, b"", msgpack.packb({"ok": True, "ready": True})])

    def _serve(self) -> None:
        poller = zmq.Poller()
        poller.register(self.sock, zmq.POLLIN)
        poller.register(self._wake_r, zmq.POLLIN)
        while not self._closed.is_set():
            events = dict(poller.poll(100))
            if self._wake_r in events:
                self._answer_waiting()
            if self.sock not in events:
                continue
            try:
                frames = self.sock.recv_multipart(zmq.NOBLOCK)
            except zmq.ZMQError:
                continue
            if len(frames) < 2:
                continue
            ident, body = frames[0], frames[-1]
            msg: Any = None
            try:
                msg = msgpack.unpackb(body)
                if not isinstance(msg, dict):
                    raise ValueError("a request is a msgpack map with a 'cmd' key")
                if msg.get("cmd") == "wait_ready" and not self.ready:
                    self._waiting.append(ident)  # answered by _answer_waiting once ready
                    continue
                reply = self.handle(msg)
            except Exception as exc:
                reply = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
            with contextlib.suppress(zmq.ZMQError):
                self.sock.send_multipart([ident, b"", msgpack.packb(reply, default=str)])
            if reply.get("stopping"):  # answered first: the CLI learns the stop began
                self._stop_run()
        for ident in self._waiting:  # the run ends before it was ready: say so rather than fall silent
            with contextlib.suppress(zmq.ZMQError):
                self.sock.send_multipart([ident, b"", msgpack.packb({"ok": False, "error": "the run stopped before it was ready"})])
        self.sock.close()

    def add_command(self, cmd: str, handler: Callable[[dict[str, Any]], dict[str, Any]]) -> None:
        """Serve ``{"cmd": cmd, ...}`` with ``handler(request) -> answer`` (on the control thread).

        An exception in ``handler`` is answered as ``{"ok": False, "error": ...}``.
        """
        if cmd in ("status", "restart", "stop", "wait_ready") or cmd in self._commands:
            raise ValueError(f"control command {cmd!r} is already served")
        self._commands[cmd] = handler

    def handle(self, msg: dict[str, Any]) -> dict[str, Any]:
        cmd = msg.get("cmd")
        if cmd == "status":
            return {
                "ok": True,
                "system": self.name,
                "run_id": self.system.run_id,
                "pid": os.getpid(),
                "uptime": round(time.monotonic() - self._t0, 1),
                "ready": self.ready,
                "rows": self.rows(),
            }
        if cmd == "wait_ready":
            return {"ok": True, "ready": self.ready}
        if cmd == "restart":
            name = msg.get("name")
            if not isinstance(name, str):
                return {"ok": False, "error": "restart needs 'name'"}
            found = on_root(self.system, lambda: self._locate(name))
            if found is None:
                names = sorted(on_root(self.system, lambda: [r["name"] for s in self.tree.roots for r in s._rows()]))
                return {"ok": False, "error": f"no child named {name!r} in this run; known: {', '.join(names) or 'none'}"}
            return {"ok": True, "pid": found.bounce(name)}
        if cmd == "stop":
            return {"ok": True, "stopping": True}
        if isinstance(cmd, str) and cmd in self._commands:
            return self._commands[cmd](msg)
        known = ", ".join(["status", "restart", "stop", "wait_ready", *self._commands])
        return {"ok": False, "error": f"unknown command {cmd!r}; one of: {known}"}

    def _locate(self, name: str) -> Any:
        for root in self.tree.roots:
            found = root._locate(name)
            if found is not None:
                return found[0]
        return None

    def rows(self) -> list[dict[str, Any]]:
        rows: list[dict[str, Any]] = on_root(self.system, lambda: [r for s in self.tree.roots for r in s._rows()])
        asks = {
            r["name"]: _ctrl_async(r["name"], "stats", self.stats_timeout)
            for r in rows
            if r["kind"] == "actor" and r["status"] == "running"
        }
        now = time.monotonic()
        deadline = now + self.stats_timeout  # one wait for all: the asks run side by side
        for r in rows:
            r.update(mailbox=None, handled=None, rate=None, drops=None, subscriptions=None)
            fut = asks.get(r["name"])
            if fut is None:
                continue
            try:
                st = fut.get(timeout=max(0.0, deadline - time.monotonic()))
            except Exception:
                continue  # hung or restarting: the row says so by its missing numbers
            r["mailbox"], r["handled"] = st["mailbox_depth"], st["handled"]
            subs = st.get("subscriptions") or []
            r["subscriptions"], r["drops"] = subs, sum(s["dropped"] for s in subs)
            r["stalled"] = st.get("stalled") or {}  # keep-all subscribers its publishers drop for
            prev = self._prev.get(r["name"])
            if prev is not None and prev[0] == st["incarnation"] and now > prev[2]:
                r["rate"] = round((st["handled"] - prev[1]) / (now - prev[2]), 1)
            else:
                r["rate"] = round(st["handled"] / max(r["uptime"], 0.1), 1)
            self._prev[r["name"]] = (st["incarnation"], st["handled"], now)
        return rows

    def _stop_run(self) -> None:
        if self.on_stop is not None:
            self.on_stop()
            return

        def stop_all() -> None:
            for root in list(self.tree.roots)[::-1]:
                root.stop()

        threading.Thread(target=stop_all, name="supervisor-stop", daemon=True).start()

    def close(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.discovery)
        self._closed.set()
        if self._thread is not threading.current_thread():
            self._thread.join(2)
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)

