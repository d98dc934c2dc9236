"""Supervisor events reach actors through the ``_supervisor.events`` topic."""

from __future__ import annotations

import time

from actors import ActorSystem
from supervisor import EVENTS_TOPIC, ChildSpec, SupervisorSpec, start_supervisor
from tests.helpers import wait_until
from tests.supervisor.conftest import ask
from tests.supervisor.workers import Echo, EventSink


def test_events_are_published_as_plain_dicts(system: ActorSystem) -> None:
    assert EVENTS_TOPIC == "_supervisor.events"
    start_supervisor(system, SupervisorSpec(intensity=10, period=60, children=[
        ChildSpec("sink", EventSink), ChildSpec("w", Echo, poison_limit=1)]))
    time.sleep(0.1)  # let the publisher connect to the new subscriber

    def crashed() -> list[dict]:
        system.ref("w").tell("crash")
        time.sleep(0.2)
        return [e for e in ask(system, "sink", "events") if e["event"] == "crashed"]

    ev = wait_until(crashed, 10, "a crashed event at the sink")[0]
    assert ev["child"] == "w" and ev["supervisor"] == "root" and ev["reason"] == "error"
    assert "ValueError: asked to crash" in ev["detail"] and isinstance(ev["time"], float)
