"""Two `embagents supervise` runs linked by their Zenoh bridges, for the tests."""

from __future__ import annotations

import contextlib
import json
import os
import queue
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

SENDER = '''
import os
from embagents import Component, String, System, Topic
from embagents.zenoh import Export, ZenohBridge, TlsFiles

chatter = Topic("chatter", String, queue_size=1000, keep="all")

class Counter(Component):
    allowed_outputs = {"Required": [String]}

    def on_activate(self):
        self.n = 0

    def _execution_step(self, **inputs):
        self.n += 1
        self.publish(chatter, String(data=str(self.n)))

system = System([Counter(name="counter", outputs=[chatter], trigger=RATE)], name=NAME,
                zenoh=ZenohBridge("robot1", exports=[Export("chatter", window=WINDOW, compress=COMPRESS)], ENDPOINTS, LINK_DOWN))
'''

RECEIVER = '''
from embagents import Component, String, System, Topic
from embagents.zenoh import Import, ZenohBridge, TlsFiles

chatter = Topic("chatter", String, queue_size=1000, keep="all")

class Printer(Component):
    allowed_inputs = {"Required": [String]}

    def _execution_step(self, **inputs):
        print("GOT", inputs["chatter"].data, flush=True)

from embagents.msgs import Health

health = Topic("_health", Health, queue_size=100, keep="all")

class HealthPrinter(Component):
    allowed_inputs = {"Required": [Health]}

    def _execution_step(self, **inputs):
        h = inputs["_health"]
        print("HEALTH", h.component, h.status.name, flush=True)

system = System([Printer(name="printer", inputs=[chatter], trigger=chatter),
                 HealthPrinter(name="health_printer", inputs=[health], trigger=health)], name=NAME,
                zenoh=ZenohBridge("gpu", imports=[Import("robot*/chatter", String, topic="chatter")], ENDPOINTS,
                                  LINK_DOWN))
'''


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def write(tmp: Path, name: str, template: str, endpoints: str, rate: float = 20.0, link_down_s: float = 2.0,
          window: int = 5000, compress: str | None = None) -> str:
    path = tmp / f"{name}.py"
    path.write_text(textwrap.dedent(template).replace("NAME", repr(name)).replace("ENDPOINTS", endpoints)
                    .replace("RATE", repr(rate)).replace("WINDOW", repr(window)).replace("COMPRESS", repr(compress)).replace("LINK_DOWN", f"link_down_s={link_down_s}"))
    return str(path)


class Run:
    """One `embagents supervise` process; its output lines in a queue."""

    def __init__(self, path: str, runs_dir: str, prefix: list[str] | None = None) -> None:
        self.env = {**os.environ, "EMBAGENTS_RUNS_DIR": runs_dir}
        self.name = Path(path).stem
        self.proc = subprocess.Popen([*(prefix or []), sys.executable, "-m", "embagents.cli", "supervise", path],
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=self.env)
        self.lines: queue.Queue[str] = queue.Queue()
        self.all: list[str] = []

        def pump() -> None:
            for line in self.proc.stdout or ():
                self.all.append(line)
                self.lines.put(line)

        threading.Thread(target=pump, daemon=True).start()

    def got(self) -> list[int]:
        return [int(x.split()[1]) for x in list(self.all) if x.startswith("GOT ")]

    def status(self, prefix: list[str] | None = None) -> dict[str, Any] | None:
        out = subprocess.run([*(prefix or []), sys.executable, "-m", "embagents.cli", "status", "--json", "--run",
                              self.name], capture_output=True, text=True, timeout=60, env=self.env)
        if out.returncode != 0:
            return None
        return json.loads(out.stdout)  # type: ignore[no-any-return]

    def bridge(self, prefix: list[str] | None = None) -> dict[str, Any] | None:
        st = self.status(prefix)
        rows = {r["name"]: r for r in (st or {}).get("rows", [])}
        return (rows.get("_zenoh_bridge") or {}).get("detail")

    def kill_bridge(self, restarts: int) -> None:
        """SIGKILL this run's Zenoh bridge and wait until its supervisor has restarted it (``restarts`` in all)."""
        import os
        import signal

        rows = {r["name"]: r for r in self.status()["rows"]}  # type: ignore[index]
        os.kill(rows["_zenoh_bridge"]["pid"], signal.SIGKILL)
        wait_for(lambda: {r["name"]: r for r in (self.status() or {"rows": []})["rows"]}
                 .get("_zenoh_bridge", {}).get("restarts") == restarts, 30, f"the bridge's restart {restarts}")

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode


@contextlib.contextmanager
def linked(tmp: Path, name: str, **sender: Any) -> Iterator[tuple[Run, Run]]:
    """Run ``NAME_a`` (SENDER, ``write``'s ``sender`` options, listening on a free loopback port) and ``NAME_b``
    (RECEIVER, connecting to it); both are stopped after, B first."""
    port, runs = free_port(), str(tmp / "runs")
    a = Run(write(tmp, f"{name}_a", SENDER, f"listen=['tcp/127.0.0.1:{port}']", **sender), runs)
    try:
        b = Run(write(tmp, f"{name}_b", RECEIVER, f"connect=['tcp/127.0.0.1:{port}']"), runs)
        try:
            yield a, b
        finally:
            b.stop()
    finally:
        a.stop()


def wait_for(fn: Callable[[], Any], timeout: float, what: str) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = fn()
        if value:
            return value
        time.sleep(0.2)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")
