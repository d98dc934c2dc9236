from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from actors import ActorSystem
from actors.loop import Loop
from actors.runtime import Runtime
from actors.topics import Publisher as TopicPublisher
from actors.topics import Subscription
from tests.actors.workers import Publisher, Subscriber
from tests.helpers import wait_until


def test_publish_reaches_a_subscriber_in_another_process(system: ActorSystem) -> None:
    sub = system.spawn(Subscriber, "sub", "chatter")
    pub = system.spawn(Publisher, "pub")

    def got() -> list[Any]:
        pub.ask(["chatter", {"n": 1}], timeout=5).get()
        return sub.ask("got", timeout=5).get()

    assert {"n": 1} in wait_until(got)


def test_large_frames_travel_through_shared_memory(system: ActorSystem) -> None:
    sub = system.spawn(Subscriber, "sub", "camera")
    pub = system.spawn(Publisher, "pub")
    frame = np.arange(300_000, dtype=np.int32)

    def got() -> list[Any]:
        pub.ask(["camera", frame], timeout=5).get()
        return [g for g in sub.ask("got", timeout=5).get() if isinstance(g, list) and g[0] == "array"]

    out = wait_until(got)
    assert out[0][1] == [300_000] and out[0][2] == 299_999


def test_keep_latest_drops_the_oldest(system: ActorSystem) -> None:
    sub = system.spawn(Subscriber, "sub", "burst", 3, "latest")
    pub = system.spawn(Publisher, "pub")
    wait_until(lambda: (pub.ask(["burst", -1], timeout=5).get(), sub.ask("got", timeout=5).get())[1])
    # Block the subscriber, then publish a burst: only the newest 3 survive.
    sub.tell("got")
    for i in range(50):
        pub.tell(["burst", i])
    pub.flush(5)
    time.sleep(0.3)
    got = sub.ask("got", timeout=5).get()
    assert got[-1] == 49


def test_a_subscription_in_the_publishers_own_thread_confirms_at_once(tmp_path: Path) -> None:
    # ZeroMQ runs a socket's commands only in its owner's calls: without a nudge, our own
    # SUBSCRIBE would only arrive after the publisher's wait timed out.
    rt, loop, got = Runtime(str(tmp_path), "tt"), Loop(), []
    sub = Subscription(rt, loop, "loopback", got.append)
    pub = TopicPublisher(rt, "loopback")
    try:
        assert pub.subscribers == 1
        assert pub.unconfirmed == 0
        pub.publish({"n": 1})
        loop.run(until=lambda: bool(got), timeout=10.0)
        assert got == [{"n": 1}]
    finally:
        sub.close()
        pub.close()
        loop.close()
        rt.close()
