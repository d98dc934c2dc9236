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
  is ready (at once if it is; an error if the run ends first): a blocking
  request, no polling. The run is ready when the layer above says so
  (:meth:`ControlServer.mark_ready`), or, unless it
  :meth:`~ControlServer.hold_ready`, once the tree has started. ``status``
  answers ``ready`` too.
- any command the layer above adds with :meth:`ControlServer.add_command`
  (``embagents supervise`` adds ``publish``: a message on a topic of the system).

Every request may carry ``deadline`` (:func:`time.monotonic` seconds, the
clock every process of this machine shares: when its sender stops waiting)
and ``id`` (any value, echoed in the answer so a DEALER client can match
answers to requests). A request whose deadline has passed when the root gets
to it is not carried out (answered ``{"ok": False, "expired": True}``), so a
command its sender reported as failed never happens later; ``restart``
checks it again when the supervisor starts the job. The control thread only
receives and answers: every command but ``stop`` runs on a thread of its
own (at most :data:`MAX_IN_FLIGHT` at once), so a slow ``call`` never holds
up ``status``.

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

import collections
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
from supervisor.errors import SupervisorError
from supervisor.rootio import on_root
from supervisor.tree import Tree

__all__ = ["MAX_IN_FLIGHT", "ControlServer", "control_endpoint", "expired", "runs_dir"]

log = logging.getLogger("supervisor.control")

#: Requests served at once; one more is refused at once (``busy``) rather than queued.
MAX_IN_FLIGHT = 64


def expired(msg: dict[str, Any]) -> dict[str, Any] | None:
    """The answer to ``msg`` if its ``deadline`` has passed (logged: it is not carried out), else None."""
    deadline = msg.get("deadline")
    if deadline is None:
        return None
    late = time.monotonic() - deadline
    if late <= 0:
        return None
    log.info("control: %s not carried out: its deadline passed %.2f s before the run got to it", msg.get("cmd"), late)
    return {"ok": False, "expired": True,
            "error": f"{msg.get('cmd')} not carried out: its deadline passed {late:.2f} s before the run got to it "
                     "(a longer --timeout gives it more time)"}


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
    """Serves control requests (see the module docs); writes and removes the discovery file."""

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
        self._rows_lock = threading.Lock()  # status requests run side by side; _prev is shared
        # Answers from worker threads: queued here, the control thread woken through a pipe (it owns the socket).
        self._answers: collections.deque[tuple[list[bytes], dict[str, Any]]] = collections.deque()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        self._wake_lock = threading.Lock()  # the pipe is closed once, never written after
        self._in_flight = 0
        self.ready = False
        self.ready_held = False
        self._ready_or_closed = threading.Event()  # wait_ready requests wait on it
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
        self._ready_or_closed.set()

    def _wait_ready(self, msg: dict[str, Any]) -> dict[str, Any]:
        """Answer once the run is ready, or ends, or the request's deadline passed (its worker thread waits)."""
        deadline = msg.get("deadline")
        self._ready_or_closed.wait(None if deadline is None else max(0.0, deadline - time.monotonic()))
        if self.ready:
            return {"ok": True, "ready": True}
        if self._closed.is_set():
            return {"ok": False, "error": "the run stopped before it was ready"}
        return {"ok": False, "ready": False, "error": "the run is not ready yet"}

    # -- serving (its own thread: it receives and answers; commands run on worker threads) ----
    def _serve(self) -> None:
        poller = zmq.Poller()
        poller.register(self.sock, zmq.POLLIN)
        poller.register(self._wake_r, zmq.POLLIN)
        while True:
            ready = dict(poller.poll())
            if self._wake_r in ready:
                with contextlib.suppress(BlockingIOError):
                    os.read(self._wake_r, 4096)
                while self._answers:
                    self._send(*self._answers.popleft())
                    self._in_flight -= 1  # only this thread counts: no lock
            if self._closed.is_set():
                break
            if self.sock in ready:
                while True:
                    try:
                        frames = self.sock.recv_multipart(zmq.NOBLOCK)
                    except zmq.ZMQError:
                        break
                    if len(frames) >= 2:
                        self._take(frames[:-1], frames[-1])
        self.sock.close()
        with self._wake_lock:
            os.close(self._wake_r)
            os.close(self._wake_w)
            self._wake_r = self._wake_w = -1

    def _take(self, envelope: list[bytes], body: bytes) -> None:
        """One request (control thread): answered at once if it is bad, late, ``stop`` or one too many."""
        msg: Any = None
        try:
            msg = msgpack.unpackb(body)
            if not isinstance(msg, dict):
                raise ValueError("a request is a msgpack map with a 'cmd' key")
            if msg.get("deadline") is not None and not isinstance(msg["deadline"], (int, float)):
                raise ValueError(f"'deadline' is time.monotonic() seconds, got {msg['deadline']!r}")
        except Exception as exc:
            self._send(envelope, {"ok": False, "error": f"{type(exc).__name__}: {exc}"}, msg if isinstance(msg, dict) else None)
            return
        late = expired(msg)
        if late is not None:
            self._send(envelope, late, msg)
        elif msg.get("cmd") == "stop":
            self._send(envelope, {"ok": True, "stopping": True}, msg)
            self._stop_run()  # answered first: the CLI learns the stop began
        elif self._in_flight >= MAX_IN_FLIGHT:
            self._send(envelope, {"ok": False, "busy": True, "error": f"the run is serving {self._in_flight} "
                                  "control requests already; try again when some have answered"}, msg)
        else:
            self._in_flight += 1
            threading.Thread(target=self._work, args=(envelope, msg), name=f"control-{msg.get('cmd')}",
                             daemon=True).start()

    def _work(self, envelope: list[bytes], msg: dict[str, Any]) -> None:
        """Serve one request on this worker thread; the control thread sends the answer."""
        try:
            reply = expired(msg) or self.handle(msg)  # a thread may start late on a busy machine
        except Exception as exc:
            reply = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
        with self._wake_lock:
            if self._wake_w < 0:
                return  # closed: nobody to answer
            self._answers.append((envelope, self._tagged(reply, msg)))
            os.write(self._wake_w, b"\0")

    @staticmethod
    def _tagged(reply: dict[str, Any], msg: dict[str, Any]) -> dict[str, Any]:
        return {**reply, "id": msg["id"]} if "id" in msg else reply

    def _send(self, envelope: list[bytes], reply: dict[str, Any], msg: dict[str, Any] | None = None) -> None:
        if msg is not None:
            reply = self._tagged(reply, msg)
        with contextlib.suppress(zmq.ZMQError):  # a sender that gave up is gone: the ROUTER drops its answer
            self.sock.send_multipart([*envelope, msgpack.packb(reply, default=str)])

    def add_command(self, cmd: str, handler: Callable[[dict[str, Any]], dict[str, Any]]) -> None:
        """Serve ``{"cmd": cmd, ...}`` with ``handler(request) -> answer``, on a thread of the request's own.

        Requests run side by side, so ``handler`` must be thread-safe. It may
        take its time (others are served meanwhile); the request's ``deadline``
        (``time.monotonic()``, or None) says when its sender stops waiting: work
        that would start after it should not start. An exception in ``handler``
        is answered as ``{"ok": False, "error": ...}``.
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
            return self._wait_ready(msg)
        if cmd == "restart":
            name = msg.get("name")
            if not isinstance(name, str):
                return {"ok": False, "error": "restart needs 'name'"}
            found = on_root(self.system, lambda: self._locate(name))
            if found is None:
                names = sorted(on_root(self.system, lambda: [r["name"] for s in self.tree.roots for r in s._rows()]))
                return {"ok": False, "error": f"no child named {name!r} in this run; known: {', '.join(names) or 'none'}"}
            try:
                return {"ok": True, "pid": found.bounce(name, deadline=msg.get("deadline"))}
            except SupervisorError as exc:
                if exc.reason != "expired":
                    raise
                log.info("control: %s", exc)
                return {"ok": False, "expired": True, "error": str(exc)}
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
            if st.get("detail") is not None:
                r["detail"] = st["detail"]  # the actor's own (a bridge's links)
            with self._rows_lock:
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
        self._ready_or_closed.set()  # held wait_ready requests answer (if the control thread still sends)
        with self._wake_lock:
            if self._wake_w >= 0:
                os.write(self._wake_w, b"\0")  # the control thread sees _closed and ends
        if self._thread is not threading.current_thread():
            self._thread.join(2)

