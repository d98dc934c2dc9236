from __future__ import annotations

import logging
import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
import zmq

from actors import ActorSystem
from actors.forkserver import cleanup_pid
from actors.loop import Loop
from actors.runtime import Runtime
from actors.topics import Publisher as TopicPublisher
from actors.topics import Subscription, mark_changed
from tests.actors.workers import Burst, Holder, Publisher, Subscriber, TopicCounter
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


def test_keep_all_loses_nothing_while_both_sides_live(system: ActorSystem) -> None:
    # A burst far past every high-water mark into a slow subscriber with a small queue:
    # the publisher is slowed, not the stream thinned.
    sub = system.spawn(TopicCounter, "sub", "numbers", 10, "all", 0.0005)
    pub = system.spawn(Burst, "pub")
    wait_until(lambda: pub.ask(["numbers", 1], timeout=5).get() and sub.ask("stats", timeout=5).get()["got"])
    n = 5001
    pub.ask(["numbers", n], timeout=60).get()
    st = wait_until(lambda: (s := sub.ask("stats", timeout=5).get())["last"] == n - 1 and s, timeout=60)
    assert st["distinct"] == n and st["ordered"], st
    assert st["dropped"] == 0 and st["bad"] == 0, st


def test_keep_latest_counts_every_message_it_drops(system: ActorSystem) -> None:
    sub = system.spawn(TopicCounter, "sub", "numbers", 3, "latest", 0.001)
    pub = system.spawn(Burst, "pub")
    wait_until(lambda: pub.ask(["numbers", 1], timeout=5).get() and sub.ask("stats", timeout=5).get()["got"])
    before = sub.ask("stats", timeout=5).get()
    n = 3000
    pub.ask(["numbers", n], timeout=60).get()
    time.sleep(0.5)  # the burst's tail may have been dropped: a later message reveals the gap
    pub.ask(["numbers", 1], timeout=5).get()
    st = wait_until(lambda: (s := sub.ask("stats", timeout=5).get())["last"] == 0 and s["got"] > before["got"] and s)
    got, dropped = st["got"] - before["got"], st["dropped"] - before["dropped"]
    assert dropped > 0 and got + dropped == n + 1, st  # every message is either handled or counted


def test_a_stopped_keep_all_subscriber_holds_a_publisher_only_up_to_the_stall_bound(system: ActorSystem) -> None:
    sub = system.spawn(TopicCounter, "sub", "numbers", 10, "all", 0.0)
    pub = system.spawn(Burst, "pub")
    wait_until(lambda: pub.ask(["numbers", 1], timeout=5).get() and sub.ask("stats", timeout=5).get()["got"])
    pid = sub.ask("pid", timeout=5).get()
    os.kill(pid, signal.SIGSTOP)
    try:
        n = 20_000
        pub.ask(["numbers", n], timeout=30).get()  # without the bound this never returns
        stalled = system.ctrl("pub", "stats")["stalled"]
        assert list(stalled) == ["numbers"] and len(stalled["numbers"]) == 1, stalled
    finally:
        os.kill(pid, signal.SIGCONT)
    # Once it has caught up, a later message reaches it and reveals the dropped tail's gap.
    total = 0

    def caught_up() -> dict[str, Any] | None:
        nonlocal total
        total = pub.ask(["numbers", 1], timeout=5).get()["total"]
        s = sub.ask("stats", timeout=5).get()
        return s if s["last"] == 0 and s["got"] > 1 else None

    st = wait_until(caught_up, timeout=30, interval=0.2)
    assert st["dropped"] > 0 and st["got"] + st["dropped"] == total, st  # counted, not vanished
    assert not system.ctrl("pub", "stats")["stalled"]  # it reads again: the publisher says so


def test_garbage_on_a_subscription_socket_is_counted_and_skipped(system: ActorSystem) -> None:
    sub = system.spawn(TopicCounter, "sub", "numbers", 10, "all", 0.0)
    pub = system.spawn(Burst, "pub")
    wait_until(lambda: pub.ask(["numbers", 1], timeout=5).get() and sub.ask("stats", timeout=5).get()["got"])
    [mark] = os.listdir(os.path.join(system.run_dir, "topics", "numbers"))
    ctx = zmq.Context.instance()
    push = ctx.socket(zmq.PUSH)
    push.setsockopt(zmq.LINGER, 1000)
    push.connect(f"ipc://{system.run_dir}/s.{mark}")
    for junk in [b"", b"\x00" * 16, b"\x01" * 16 + b"\xc1", b"\x02" * 16 + msgpack.packb([1, 2])[:1]]:
        push.send(junk)
    push.close()
    pub.ask(["numbers", 3], timeout=5).get()
    st = wait_until(lambda: (s := sub.ask("stats", timeout=5).get())["bad"] >= 4 and s["last"] == 2 and s)
    assert st["bad"] == 4, st


def test_a_frame_of_ten_thousand_nested_messages_is_counted_and_skipped(system: ActorSystem) -> None:
    from tests.actors.test_codec import nested_frame

    sub = system.spawn(TopicCounter, "sub", "numbers", 10, "latest", 0.0)
    pub = system.spawn(Burst, "pub")
    wait_until(lambda: pub.ask(["numbers", 1], timeout=5).get() and sub.ask("stats", timeout=5).get()["got"])
    pid = sub.ask("pid", timeout=5).get()
    [mark] = os.listdir(os.path.join(system.run_dir, "topics", "numbers"))
    xpub = zmq.Context.instance().socket(zmq.XPUB)  # a publisher of its own, as another process could be
    xpub.setsockopt(zmq.LINGER, 1000)
    xpub.connect(f"ipc://{system.run_dir}/s.{mark}")
    try:
        assert xpub.poll(5000) and xpub.recv()[:1] == b"\x01"  # the subscription is live
        for levels in (200, 10_000):  # 200 levels used to kill the subscriber with SIGSEGV
            xpub.send(b"\x07" * 8 + levels.to_bytes(8, "little") + nested_frame(levels))  # a number each (or: seen)
        st = wait_until(lambda: (s := sub.ask("stats", timeout=5).get())["bad"] >= 2 and s)
    finally:
        xpub.close()
    assert st["bad"] == 2 and sub.ask("pid", timeout=5).get() == pid
    pub.ask(["numbers", 3], timeout=5).get()
    wait_until(lambda: sub.ask("stats", timeout=5).get()["last"] == 2)  # it goes on: 0, 1, 2 arrive


def test_publishes_and_tells_of_large_arrays_from_two_threads_keep_their_own_memory(system: ActorSystem) -> None:
    # A topic's frames go into its ring (reused after 8 newer frames); a tell's into segments kept
    # until acknowledged. Encoding one on another thread must never put it in the other's place.
    holder = system.spawn(Holder, "holder")
    sub = system.spawn(Subscriber, "sub", "frames", 1, "latest")
    pub = TopicPublisher(system.rt, "frames")
    wait_until(lambda: sub.ask("got", timeout=5).get(), poke=lambda: pub.publish(np.zeros(1 << 17, np.uint8)))
    stop = threading.Event()

    def publish() -> None:
        while not stop.is_set():
            pub.publish(np.full(1 << 17, 255, np.uint8))

    t = threading.Thread(target=publish)
    t.start()
    try:
        n = 60
        for i in range(n):
            holder.tell(np.full(1 << 17, i, np.uint8))
        assert holder.flush(30)
    finally:
        stop.set()
        t.join()
        pub.close()
    assert holder.ask("sum", timeout=10).get() == [i << 17 for i in range(n)]


def test_a_keep_all_subscriber_stopped_for_good_makes_its_publisher_hold_only_a_window_for_a_while(
        system: ActorSystem, caplog: pytest.LogCaptureFixture) -> None:
    sub = system.spawn(TopicCounter, "sub", "numbers", 10, "all", 0.0)
    pub = TopicPublisher(system.rt, "numbers")
    pub.successor_timeout = 1.0
    try:
        wait_until(lambda: sub.ask("stats", timeout=5).get()["got"], poke=lambda: pub.publish(0))
        system.stop("sub")
        wait_until(lambda: not pub.subscribers, 5, "the mark's removal")
        with caplog.at_level(logging.WARNING, logger="actors.topics"):
            for i in range(3 * pub.window):
                pub.publish(i)
            assert pub.held == pub.window and pub.dropped == 2 * pub.window  # kept for a successor: a window
            assert "is gone and 256 messages are kept for it" in caplog.text
            time.sleep(1.1)
            pub.publish(-1)
            assert pub.held == 0  # past successor_timeout: let go, and said so
            assert "did not come back within 1 s: dropped the 768 message(s)" in caplog.text
    finally:
        pub.close()


def test_a_publisher_sees_subscriptions_come_and_go_without_listing_the_folder_at_each_publish(tmp_path: Path) -> None:
    rt, loop, got = Runtime(str(tmp_path), "seen"), Loop(), []
    pub = TopicPublisher(rt, "events")
    subs: list[Subscription] = []
    try:
        assert pub.subscribers == 0
        pub.publish({"n": 0})  # nobody: not sent
        subs.append(Subscription(rt, loop, "events", got.append, keep="all"))
        subs.append(Subscription(rt, loop, "events", got.append))
        assert pub.subscribers == 2
        pub.publish({"n": 1})
        assert loop.run(until=lambda: len(got) == 2, timeout=5), got
        subs.pop().close()
        assert pub.subscribers == 1
        # A subscription whose process died, removed by the fork server's cleanup, is seen gone too.
        folder = os.path.dirname(subs[0]._mark)
        Path(folder, "999999-0-all").touch()
        mark_changed(folder)
        assert pub.subscribers == 2
        cleanup_pid(str(tmp_path), "none_", 999999)
        assert pub.subscribers == 1
        pub.publish({"n": 2})
        assert loop.run(until=lambda: len(got) == 3, timeout=5), got
        assert [m["n"] for m in got] == [1, 1, 2]
    finally:
        for s in subs:
            s.close()
        pub.close()
        loop.close()
        rt.close()


def test_a_subscription_woken_with_nothing_to_read_reads_nothing(tmp_path: Path) -> None:
    rt, loop, got = Runtime(str(tmp_path), "idle"), Loop(), []
    sub = Subscription(rt, loop, "quiet", got.append, keep="all")
    try:
        sub.on_readable()  # a spurious wake: no message, no error
        assert (got, sub.received, sub.bad) == ([], 0, 0)
    finally:
        sub.close()
        loop.close()
        rt.close()


def test_a_publisher_keeps_for_a_durable_subscriber_only_what_it_has_not_acknowledged(tmp_path: Path) -> None:
    rt, loop, got = Runtime(str(tmp_path), "keep"), Loop(), []
    sub = Subscription(rt, loop, "blobs", got.append, queue_size=4, keep="all", key="sink#0")
    pub = TopicPublisher(rt, "blobs")
    try:
        blob = b"x" * (512 << 10)
        for i in range(40):  # 20 MiB, read as it goes: past 8 MiB kept, the acknowledged ones are let go
            pub.publish(blob)
            assert loop.run(until=lambda i=i: len(got) == i + 1, timeout=5)
        assert pub.kept <= (8 << 20) + len(blob) + 64, pub.kept
        assert pub.kept > 0  # the window's frames are kept for its next incarnation until trimmed
    finally:
        pub.close()
        sub.close()
        rt.close()


def test_a_raw_subscription_relays_frames_undecoded_and_the_receiver_decodes_or_refuses_them(tmp_path: Path) -> None:
    # A relay (the Zenoh bridge) sends a frame on as it came: no decode, no encode.
    rt, loop, frames, got = Runtime(str(tmp_path), "raw"), Loop(), [], []
    raw = Subscription(rt, loop, "in", frames.append, keep="all", raw=True)
    out = Subscription(rt, loop, "out", got.append, keep="all")
    pub_in, pub_out = TopicPublisher(rt, "in"), TopicPublisher(rt, "out")
    try:
        msg = {"n": 1, "a": np.arange(4, dtype=np.int16)}
        pub_in.publish(msg)
        loop.run(until=lambda: bool(frames), timeout=10.0)
        assert isinstance(frames[0], memoryview) and bytes(frames[0]) == rt.codec.encode(msg)[0]
        assert raw.decode(frames[0])["n"] == 1
        pub_out.publish_frame(frames[0])
        pub_out.publish_frame(b"\xc1 is no msgpack")  # a peer's garbage: the receiver's decoder refuses it
        pub_out.publish_frame(rt.codec.encode({"n": 2})[0])
        loop.run(until=lambda: len(got) >= 2, timeout=10.0)
        assert got[0]["n"] == 1 and np.array_equal(got[0]["a"], msg["a"]) and got[1] == {"n": 2}
        assert out.bad == 1 and out.received == 3
        with pytest.raises(ValueError, match="cannot check msg_type"):
            Subscription(rt, loop, "typed", got.append, raw=True, msg_type=dict)
    finally:
        for s in (raw, out):
            s.close()
        pub_in.close()
        pub_out.close()
        loop.close()
        rt.close()


def test_a_relay_restarted_under_its_sources_publisher_id_is_heard_once_and_a_jump_is_counted(tmp_path: Path) -> None:
    # A Zenoh bridge publishes a source's samples under that source's id and numbers; its successor after a
    # kill sends the last ones again (the killed one may not have got them out): each subscription drops
    # the numbers it had, keep-all and keep-latest alike, and counts a jump as dropped.
    rt, loop, kept, latest = Runtime(str(tmp_path), "relay"), Loop(), [], []
    subs = [Subscription(rt, loop, "relayed", kept.append, keep="all", queue_size=100),
            Subscription(rt, loop, "relayed", latest.append, keep="latest", queue_size=100)]
    pubs = []
    try:
        with pytest.raises(ValueError, match="48 bits"):
            TopicPublisher(rt, "relayed", pub_id=1 << 48)
        first = TopicPublisher(rt, "relayed", pub_id=0xBEEF)
        pubs.append(first)
        for n in range(1, 6):
            first.publish_frame(rt.codec.encode({"n": n})[0], seq=n)
        assert loop.run(until=lambda: len(kept) == 5 and len(latest) == 5, timeout=10)
        first.close()
        pubs.remove(first)
        again = TopicPublisher(rt, "relayed", pub_id=0xBEEF)  # the restarted relay
        pubs.append(again)
        for n in [3, 4, 5, 6, 7, 9]:
            again.publish({"n": n}, seq=n)
        assert loop.run(until=lambda: len(kept) == 8 and len(latest) == 8, timeout=10)
        loop.run(until=lambda: False, timeout=0.2)  # nothing more comes
        for got, sub in zip((kept, latest), subs, strict=True):
            assert [m["n"] for m in got] == [1, 2, 3, 4, 5, 6, 7, 9]
            assert sub.dropped == 1 and sub.received == 11
    finally:
        for s in subs:
            s.close()
        for p in pubs:
            p.close()
        loop.close()
        rt.close()
