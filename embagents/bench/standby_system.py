"""The system the ``standby_takeover`` case runs: one component whose ``on_configure`` takes seconds.

``slow`` stands for a CUDA model (6.7 s to import torch, create the context,
build and warm the model, measured on an H200): its ``on_configure`` sleeps
``EMBAGENTS_BENCH_CONFIGURE_S`` seconds (default 5). It is a server (no
trigger): ``Call("record", [n])`` tells are its keep-all input (its
mailbox), each number appended to ``$EMBAGENTS_BENCH_OUT/rec-<pid>.log`` as
``T n`` with one ``write`` (a SIGKILL loses no record of a handled message);
the same numbers on the ``keep="all"`` topic ``standby_numbers`` are recorded
as ``S n``; ``Call("pid")`` answers with its process id. ``EMBAGENTS_BENCH_STANDBY=1`` gives it a warm standby.

Run by hand: ``embagents supervise embagents/bench/standby_system.py``.
"""

from __future__ import annotations

import os
import time
from typing import Any

from embagents.components import Component
from embagents.msgs import String
from embagents.system import System
from embagents.topic import Topic

NUMBERS = Topic("standby_numbers", String, queue_size=1000, keep="all")


class SlowConfigure(Component):
    """Configures for seconds, then records numbers it is told."""

    def on_configure(self) -> None:
        time.sleep(float(os.environ.get("EMBAGENTS_BENCH_CONFIGURE_S", "5")))

    def record(self, n: int, how: str = "T") -> None:
        out = os.environ.get("EMBAGENTS_BENCH_OUT", "/tmp")
        fd = os.open(os.path.join(out, f"rec-{os.getpid()}.log"), os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o600)
        try:
            os.write(fd, f"{how} {n}\n".encode())
        finally:
            os.close(fd)

    def on_message(self, topic_name: str, msg: Any, now: float | None = None) -> bool:
        if topic_name == NUMBERS.name:
            self.record(int(msg.data), "S")
        return super().on_message(topic_name, msg, now)

    def pid(self) -> int:
        return os.getpid()


system = System(
    [SlowConfigure(name="slow", inputs=[NUMBERS], standby=os.environ.get("EMBAGENTS_BENCH_STANDBY") == "1")],
    name="standby_bench", external=[NUMBERS],
)
