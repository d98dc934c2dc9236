"""A real root process for the end-to-end tests: ``python -m tests.supervisor.rootproc MODE OUT``.

It supervises an actor, an external command and a nested supervisor with
another actor, writes their pids (and the fork server's) to OUT as JSON once
all are ready, and serves until stopped.
"""

from __future__ import annotations

import json
import logging
import os
import sys

from supervisor import ChildSpec, Command, SupervisorSpec
from supervisor.rootio import on_root
from supervisor.run import serve
from tests.supervisor.workers import Echo  # noqa: I001  (before the fork server starts)


def main(mode: str, out: str) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    if mode == "giveup":
        spec = SupervisorSpec(intensity=0, children=[ChildSpec("flaky", Command(["sh", "-c", "sleep 0.3; exit 1"]))])
    else:
        inner = SupervisorSpec(children=[ChildSpec("deep", Echo)])
        spec = SupervisorSpec(children=[
            ChildSpec("echo", Echo),
            ChildSpec("cmd", Command(["sleep", "600"])),
            ChildSpec("inner", inner),
        ])

    def ready(sup, control) -> None:
        def pids() -> dict[str, int]:
            rows = [r for s in sup.tree.roots for r in s._rows()]
            return {r["name"]: r["pid"] for r in rows}

        info = on_root(sup.system, pids)
        info["forkserver"] = sup.system.forkserver.pid
        info["run_dir"] = sup.system.run_dir
        with open(out + ".tmp", "w") as f:
            json.dump(info, f)
        os.replace(out + ".tmp", out)

    return serve(spec, system_name=f"e2e-{mode}", on_ready=ready)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2]))
