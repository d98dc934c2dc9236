"""The per-process runtime: ZeroMQ context, shared memory, links and IO loops.

Every process of a run (the root and each actor process) has exactly one
:class:`Runtime`. Refs use it to find the IO loop of the calling thread:
an actor process's main thread is its own loop, so asks from a handler go
straight to the socket; any other thread goes through a lazily started
client IO thread.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
from collections.abc import Callable, Iterator
from typing import Any

import msgpack
import zmq

from actors import wire
from actors.codec import Codec
from actors.errors import ActorError, ActorNotFound
from actors.link import Link
from actors.loop import Loop
from actors.shm import ShmPool, ShmReader

log = logging.getLogger("actors.runtime")

__all__ = ["Runtime", "current", "registry_path"]

_current: Runtime | None = None
_current_lock = threading.Lock()


def registry_path(run_dir: str, name: str = "") -> str:
    return os.path.join(run_dir, "reg", name)


def shm_prefix(run_id: str, pid: int | None = None) -> str:
    """Segment-name prefix of a run, or of one process of the run."""
    return f"ea{run_id}_" if pid is None else f"ea{run_id}_{pid}_"


class Runtime:
    """Process-wide state of one run."""

    def __init__(self, run_dir: str, run_id: str) -> None:
        self.run_dir = run_dir
        self.run_id = run_id
        self.pid = os.getpid()
        self.ctx = zmq.Context()
        self.pool = ShmPool(shm_prefix(run_id, self.pid))
        self.reader = ShmReader(pool=self.pool, prefix=shm_prefix(run_id))
        self.codec = Codec(self.pool, self.reader)
        self._loops: dict[int, Loop] = {}
        self._links: dict[tuple[int, str], Link] = {}
        self._owner_loop: dict[int, Loop] = {}
        self._client: Loop | None = None
        self._client_thread: threading.Thread | None = None
        self._client_error: BaseException | None = None  # what stopped the IO thread, if anything
        self._lock = threading.Lock()
        self.closed = False
        #: Set by an actor host: lets library code waiting on something say "alive, working".
        self.beat: Callable[[], None] = lambda: None

    # -- names --------------------------------------------------------------
    def endpoint(self, name: str) -> str:
        return f"ipc://{self.run_dir}/{name}.mb"

    def lookup(self, name: str) -> dict[str, Any]:
        """The registry entry of actor ``name``; :class:`ActorNotFound` if none."""
        wire.check_name(name)
        try:
            with open(registry_path(self.run_dir, name), "rb") as f:
                return msgpack.unpackb(f.read())
        except FileNotFoundError:
            raise ActorNotFound(name, self.names()) from None

    def names(self) -> list[str]:
        try:
            return sorted(os.listdir(registry_path(self.run_dir)))
        except FileNotFoundError:
            return []

    def register(self, name: str, entry: dict[str, Any]) -> None:
        os.makedirs(registry_path(self.run_dir), mode=0o700, exist_ok=True)
        tmp = registry_path(self.run_dir, f".{name}.tmp")
        with open(tmp, "wb") as f:
            f.write(msgpack.packb(entry))
        os.replace(tmp, registry_path(self.run_dir, name))

    def unregister(self, name: str) -> None:
        try:
            os.unlink(registry_path(self.run_dir, name))
        except FileNotFoundError:
            pass

    # -- loops --------------------------------------------------------------
    def adopt_loop(self, loop: Loop) -> None:
        """Make ``loop`` the IO loop of the calling thread."""
        self._loops[threading.get_ident()] = loop

    @contextlib.contextmanager
    def thread_loop(self) -> Iterator[Loop]:
        """Give the calling thread an IO loop of its own while inside (a driver thread that asks actors).

        Its asks then go out on links of its own and ``get()`` blocks on their
        socket, as an actor's handler does: no hand-over to the client IO
        thread and back (two wake-ups, ~90 us on a busy machine). Its links
        are closed on the way out, in this thread; leave it before the
        runtime closes. Raises RuntimeError in a thread that has a loop.
        """
        if self.loop_here() is not None:
            raise RuntimeError("this thread already has an IO loop (an actor's or the client's)")
        loop = Loop()
        self.adopt_loop(loop)
        try:
            yield loop
        finally:
            self._loops.pop(loop.thread_id, None)
            for key, link in list(self._links.items()):
                if getattr(link, "loop", None) is loop:
                    del self._links[key]
                    loop.remove(link.sock)
                    loop.remove(link.monitor)
                    link.close()
            loop.close()

    def loop_here(self) -> Loop | None:
        return self._loops.get(threading.get_ident())

    def client_loop(self) -> Loop:
        """The IO loop serving threads that have none (started on first use)."""
        with self._lock:
            if self._client is None:
                ready = threading.Event()

                def main() -> None:
                    loop = Loop()
                    self._client = loop
                    self.adopt_loop(loop)
                    ready.set()
                    try:
                        while not self.closed:
                            loop.run()
                    except BaseException as exc:
                        # A handler raised: callers waiting in on_client get this, not a silent hang.
                        self._client_error = exc
                        log.critical("the actors IO thread stopped on an error", exc_info=True)

                t = threading.Thread(target=main, name="actors-io", daemon=True)
                t.start()
                ready.wait()
                self._client_thread = t
            assert self._client is not None  # set by main() before ready
            return self._client

    def on_client(self, fn: Callable[[], Any]) -> Any:
        """Run ``fn`` on the client IO thread and return its result."""
        loop = self.client_loop()
        if threading.get_ident() == loop.thread_id:
            return fn()  # already on the IO thread: waiting for ourselves would deadlock
        done = threading.Event()
        box: list[Any] = []

        def call() -> None:
            try:
                box.append((True, fn()))
            except BaseException as exc:  # handed back to the caller
                box.append((False, exc))
            done.set()

        loop.call_soon_threadsafe(call)
        thread = self._client_thread
        while not done.wait(1.0):
            if thread is not None and not thread.is_alive() and not done.is_set():
                raise ActorError(f"the actors IO thread of this process is gone ({self._client_error!r}), so "
                                 "nothing can be sent or received: see the log above; stop the run and start it again")
        ok, value = box[0]
        if not ok:
            raise value
        return value

    def link(self, name: str, loop: Loop) -> Link:
        """The link from ``loop``'s thread to actor ``name`` (created on first use)."""
        key = (loop.thread_id, name)
        link = self._links.get(key)
        if link is None or link.closed:
            entry = self.lookup(name)
            link = Link(self, name, entry["endpoint"])
            link.loop = loop  # type: ignore[attr-defined]
            loop.add(link.sock, link.on_readable)
            loop.add(link.monitor, link.on_monitor)
            loop.after_poll.append(link.flush_releases)
            self._links[key] = link
            # The first connect is quick on ipc: wait for it so a tell is not parked
            # (not connected within 0.2 s: tells are parked until it is).
            loop.run(until=lambda: link.connected, timeout=0.2, only=[link.monitor])
        return link

    def links(self) -> list[Link]:
        return list(self._links.values())

    def drop_link(self, name: str) -> None:
        for key in [k for k in self._links if k[1] == name]:
            link = self._links.pop(key)
            loop: Loop = link.loop  # type: ignore[attr-defined]
            loop.remove(link.sock)
            loop.remove(link.monitor)
            if link.flush_releases in loop.after_poll:
                loop.after_poll.remove(link.flush_releases)
            link.close()

    def wake(self, obj: Any) -> None:
        """A view was released from some thread: make sure ``obj``'s loop flushes soon."""
        loop: Loop | None = getattr(obj, "loop", None)
        if loop is not None and loop.thread_id != threading.get_ident():
            loop.call_soon_threadsafe(lambda: None)

    def close(self) -> None:
        if self.closed:
            return
        client = self._client
        if client is not None and self._client_thread is not threading.current_thread():
            # Sockets belong to their loop's thread: close them there, then stop it.
            def finish() -> None:
                for key, link in list(self._links.items()):
                    if key[0] == client.thread_id:
                        client.remove(link.sock)
                        client.remove(link.monitor)
                        link.close()
                self.closed = True
                client.stop()

            client.call_soon_threadsafe(finish)
            if self._client_thread is not None:
                self._client_thread.join(timeout=5)
        self.closed = True
        for link in list(self._links.values()):
            link.close()
        self._links.clear()
        self.pool.close()
        self.reader.close()
        self.ctx.destroy(linger=0)


def current() -> Runtime:
    """The runtime of this process; raises if no actor system runs here."""
    if _current is None:
        raise RuntimeError(
            "no actor system in this process: create an actors.ActorSystem() first "
            "(actor processes get one automatically)"
        )
    return _current


def set_current(rt: Runtime | None) -> None:
    global _current
    with _current_lock:
        _current = rt
