"""Fixtures for supervisor tests: a fresh ActorSystem per test, an event log, helpers."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator
from typing import Any

import psutil
import pytest

import tests.supervisor.workers  # noqa: F401  (imported before any fork server starts)
from actors import ActorCrashed, ActorSystem
from supervisor.rootio import on_root
from supervisor.tree import Tree
from tests.helpers import wait_until


class EventLog:
    """Supervisor events as they happen (appended on the root IO thread)."""

    def __init__(self) -> None:
        self.items: list[dict[str, Any]] = []
        self.cond = threading.Condition()

    def add(self, ev: dict[str, Any]) -> None:
        with self.cond:
            self.items.append(ev)
            self.cond.notify_all()

    def wait(self, event: str, child: str | None = None, *, n: int = 1, timeout: float = 15.0, **match: Any) -> dict[str, Any]:
        """The n-th event of kind ``event`` (for ``child``, with fields ``match``), waiting for it."""

        def found() -> list[dict[str, Any]]:
            return [e for e in self.items if e["event"] == event and (child is None or e.get("child") == child)
                    and all(e.get(k) == v for k, v in match.items())]

        with self.cond:
            if not self.cond.wait_for(lambda: len(found()) >= n, timeout):
                raise AssertionError(f"no {n}x {event} for {child} within {timeout} s; saw {self.brief()}")
            return found()[n - 1]

    def of(self, event: str, child: str | None = None) -> list[dict[str, Any]]:
        with self.cond:
            return [e for e in self.items if e["event"] == event and (child is None or e.get("child") == child)]

    def brief(self) -> list[str]:
        return [f"{e['event']}:{e.get('child') or e.get('supervisor')}" for e in self.items]


def gone(pid: int) -> bool:
    """True if ``pid`` has exited (a zombie counts as gone)."""
    try:
        return psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True


def ask(system: ActorSystem, name: str, message: Any = "pid", timeout: float = 10.0) -> Any:
    """Ask, retrying when the ask met a dying incarnation (it fails with ActorCrashed, by design)."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            return system.ref(name).ask(message, timeout=max(0.1, deadline - time.monotonic())).get()
        except ActorCrashed:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.01)


def read_lines(path: str) -> list[str]:
    try:
        with open(path) as f:
            return f.read().splitlines()
    except FileNotFoundError:
        return []


@pytest.fixture
def system(tmp_path: Any, monkeypatch: pytest.MonkeyPatch) -> Iterator[ActorSystem]:
    monkeypatch.setenv("EMBAGENTS_RUNS_DIR", str(tmp_path / "runs"))
    s = ActorSystem()
    try:
        yield s
    finally:
        tree = Tree.of(s)
        for root in list(tree.roots):
            root.stop(20)
        tree.close()
        kids = psutil.Process(s.forkserver.pid).children()
        s.shutdown()
        assert not os.path.exists(s.run_dir), "run directory left behind"
        for p in kids:
            wait_until(lambda p=p: gone(p.pid), 5, f"exit of actor process {p.pid}")


@pytest.fixture
def events(system: ActorSystem) -> EventLog:
    log = EventLog()
    on_root(system, lambda: Tree.of(system).events.listeners.append(log.add))
    return log


@pytest.fixture
def logfile(tmp_path: Any) -> str:
    return str(tmp_path / "log.txt")
