from __future__ import annotations

import os
import signal
import threading
import time

import msgpack
import numpy as np
import pytest
import zmq

from actors import (
    ActorCrashed,
    ActorNotFound,
    ActorSystem,
    MessageTooLarge,
    RemoteError,
    Timeout,
    UnregisteredType,
    wire,
)
from tests.actors.conftest import shm_names
from tests.actors.workers import Counter, Deferrer, Echo, Forwarder, Holder


def test_ask_and_tell_reach_another_process(system: ActorSystem) -> None:
    echo = system.spawn(Echo, "echo")
    assert echo.ask("pid", timeout=5).get() != os.getpid()
    assert echo.ask({"a": [1, 2]}, timeout=5).get() == {"a": [1, 2]}
    c = system.spawn(Counter, "counter")
    for i in range(500):
        c.tell(i)
    assert c.flush(10)
    assert c.ask("seen", timeout=5).get() == list(range(500))


def test_handler_exception_reaches_the_asker_with_the_remote_traceback(system: ActorSystem) -> None:
    echo = system.spawn(Echo, "echo")
    with pytest.raises(RemoteError) as info:
        echo.ask("raise", timeout=5).get()
    assert info.value.exc_type == "ValueError" and "asked to raise" in info.value.remote_traceback
    assert echo.ask("still alive", timeout=5).get() == "still alive"


def test_refs_are_found_by_name_from_other_actor_processes(system: ActorSystem) -> None:
    system.spawn(Echo, "echo")
    fwd = system.spawn(Forwarder, "fwd")
    assert fwd.ask(["echo", "via fwd"], timeout=5).get() == "via fwd"
    with pytest.raises(RemoteError, match="no actor named 'nobody'.*known: echo, fwd"):
        fwd.ask(["nobody", 1], timeout=5).get()


def test_unknown_name_unregistered_type_and_oversize_are_clear_errors(system: ActorSystem) -> None:
    echo = system.spawn(Echo, "echo")
    with pytest.raises(ActorNotFound, match="no actor named 'ghost'"):
        system.ref("ghost")
    with pytest.raises(UnregisteredType, match="not a registered message type"):
        echo.tell(object())
    with pytest.raises(MessageTooLarge):
        echo.tell(b"x" * (system.rt.codec.max_frame_bytes + 1))
    assert echo.ask("ok", timeout=5).get() == "ok"


def test_large_arrays_arrive_as_zero_copy_views_and_come_back(system: ActorSystem) -> None:
    echo = system.spawn(Echo, "echo")
    frame = np.random.default_rng(1).integers(0, 255, (1080, 1920, 3), dtype=np.uint8)
    for _ in range(3):
        back = echo.ask(frame, timeout=5).get()
        assert back.shape == frame.shape and (back == frame).all()
        del back
    # Reused, not re-created: the pools stay small.
    assert len(shm_names(system.run_id)) <= 6


def test_attached_actor_has_the_same_ref_api(system: ActorSystem) -> None:
    ref = system.spawn(Echo, "local", attached=True)
    assert ref.ask("pid", timeout=5).get() == os.getpid()
    fwd = system.spawn(Forwarder, "fwd")
    assert fwd.ask(["local", "cross-process"], timeout=5).get() == "cross-process"


def test_ask_to_an_actor_that_dies_fails_fast_with_actor_crashed(system: ActorSystem) -> None:
    c = system.spawn(Counter, "c")
    fut = c.ask("hang", timeout=30)
    time.sleep(0.2)
    t0 = time.monotonic()
    system.signal("c", signal.SIGKILL)
    with pytest.raises(ActorCrashed, match="'c' died before answering"):
        fut.get()
    assert time.monotonic() - t0 < 5


def test_a_deferred_answer_comes_later_while_the_actor_answers_other_asks(system: ActorSystem) -> None:
    d = system.spawn(Deferrer, "d")
    first, second = d.ask("hold", timeout=10), d.ask("hold", timeout=10)
    assert d.ask("later", timeout=10).get() == "from a thread"  # resolved by another thread of the actor
    assert d.ask("held?", timeout=5).get() == 2  # answered while both wait
    assert d.ask(["release", {"x": 1}], timeout=5).get() == 0
    assert first.get() == {"x": 1} and second.get() == {"x": 1}
    failing = d.ask("hold", timeout=10)
    assert d.ask("fail", timeout=5).get() == 0
    with pytest.raises(RemoteError, match="no luck"):
        failing.get()


def test_an_ask_awaiting_a_deferred_answer_fails_when_the_actor_dies(system: ActorSystem) -> None:
    d = system.spawn(Deferrer, "d")
    held = d.ask("hold", timeout=30)
    assert d.ask("held?", timeout=5).get() == 1  # answered after "hold": that ask is acknowledged
    system.signal("d", signal.SIGKILL)
    with pytest.raises(ActorCrashed):
        held.get()


def test_a_thread_with_a_loop_of_its_own_asks_on_its_own_links_and_closes_them_on_the_way_out(
    system: ActorSystem,
) -> None:
    echo, counter = system.spawn(Echo, "echo"), system.spawn(Counter, "c")
    seen: dict[str, object] = {}

    def driver() -> None:
        with system.rt.thread_loop() as loop:
            seen["here"] = system.rt.loop_here() is loop
            seen["answer"] = echo.ask("hi", timeout=5).get()
            try:
                counter.ask("hang", timeout=0.2).get()
            except Timeout:
                seen["timeout"] = True
            seen["links"] = [link for link in system.rt.links() if getattr(link, "loop", None) is loop]
            with pytest.raises(RuntimeError, match="already has an IO loop"):
                with system.rt.thread_loop():
                    pass
        seen["after"] = [link for link in system.rt.links() if link in seen["links"]]  # type: ignore[operator]
        seen["loop after"] = system.rt.loop_here()

    t = threading.Thread(target=driver)
    t.start()
    t.join(20)
    assert seen["here"] and seen["answer"] == "hi" and seen["timeout"]
    links = seen["links"]
    assert sorted(link.name for link in links) == ["c", "echo"]  # type: ignore[attr-defined]
    assert seen["after"] == [] and all(link.closed for link in links)  # type: ignore[attr-defined]
    assert seen["loop after"] is None
    assert echo.ask("again", timeout=5).get() == "again"  # this thread's own link is untouched


def test_ask_timeout_is_pykka_timeout(system: ActorSystem) -> None:
    c = system.spawn(Counter, "c")
    with pytest.raises(Timeout):
        c.ask("hang", timeout=0.2).get()


def test_messages_to_a_dead_actor_are_delivered_to_its_next_incarnation(system: ActorSystem) -> None:
    c = system.spawn(Counter, "c")
    info = system.procs["c"]
    system.signal("c", signal.SIGKILL)
    assert info.exited.wait(5)
    for i in range(200):
        c.tell(i)
    info2 = system.start_process(info.spec)
    system.wait_ready(info2, 10)
    assert c.flush(10)
    assert c.ask("seen", timeout=5).get() == list(range(200))


def test_corrupt_and_foreign_frames_are_dropped_and_the_actor_keeps_running(system: ActorSystem) -> None:
    echo = system.spawn(Echo, "echo")
    ctx = zmq.Context.instance()
    for kind in (zmq.DEALER, zmq.REQ):
        s = ctx.socket(kind)
        s.setsockopt(zmq.LINGER, 0)
        s.connect(system.rt.endpoint("echo"))
        s.send(b"\xc1\xff garbage")
        s.send_multipart([b"two", b"parts"]) if kind == zmq.DEALER else None
        time.sleep(0.1)
        s.close()
    assert echo.ask("fine", timeout=5).get() == "fine"
    assert system.ctrl("echo", "stats")["dropped"] >= 2


def _spawn_holder_pair(system: ActorSystem) -> None:
    system.spawn(Holder, "holder")
    system.spawn(Forwarder, "sender")


def test_no_segment_leak_after_sigkill_of_the_receiver(system: ActorSystem) -> None:
    h = system.spawn(Holder, "holder")
    for _ in range(3):
        h.ask(np.ones(200_000, np.uint8), timeout=5).get()
    system.signal("holder", signal.SIGKILL)
    system.procs["holder"].exited.wait(5)
    # our (sender) segments are still owned here until the run ends; the receiver had none.
    pid = system.procs["holder"].pid
    assert [n for n in shm_names(system.run_id) if f"_{pid}_" in n] == []


def test_no_segment_leak_after_sigkill_of_the_sender(system: ActorSystem) -> None:
    system.spawn(Holder, "holder")
    fwd = system.spawn(Forwarder, "sender")
    pid = fwd.ask(["holder", "sum"], timeout=5).get() and system.procs["sender"].pid
    # The forwarder sends a large array of its own making to the holder, which keeps it.
    big = np.full(300_000, 3, np.uint8)
    assert fwd.ask(["holder", big], timeout=5).get() == 1
    system.signal("sender", signal.SIGKILL)
    system.procs["sender"].exited.wait(5)
    time.sleep(0.2)
    assert [n for n in shm_names(system.run_id) if f"_{pid}_" in n] == []


def test_shutdown_leaves_nothing(tmp_path: object) -> None:
    s = ActorSystem()
    e = s.spawn(Echo, "echo")
    e.ask(np.ones(100_000, np.uint8), timeout=5).get()
    pids = [s.procs["echo"].pid, s.forkserver.pid]
    s.shutdown()
    assert shm_names(s.run_id) == [] and not os.path.exists(s.run_dir)
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)


def test_held_replies_are_never_overwritten(system: ActorSystem) -> None:
    echo = system.spawn(Echo, "echo")
    held = []
    for i in range(12):
        a = np.full(1 << 20, i, np.uint8)
        held.append(echo.ask(a, timeout=5).get())
    # Every reply we still hold keeps its own bytes: no segment was reused under it.
    assert [int(h[0]) for h in held] == list(range(12))
    assert all(int(h[-1]) == i for i, h in enumerate(held))


def test_held_replies_in_an_actor_process_are_never_overwritten(system: ActorSystem) -> None:
    from tests.actors.workers import Keeper

    system.spawn(Echo, "echo")
    keeper = system.spawn(Keeper, "keeper")
    assert keeper.ask(["echo", 20], timeout=30).get() == list(range(20))


def test_segments_are_recycled_when_replies_are_dropped_inside_a_handler(system: ActorSystem) -> None:
    from tests.actors.workers import Looper

    system.spawn(Echo, "echo")
    looper = system.spawn(Looper, "looper")
    assert looper.ask(["echo", 40], timeout=60).get() == 39
    # Views dropped inside the handler's loop are released with the next ask, so both
    # sides reuse a couple of hot segments instead of creating forty.
    for name in ("echo", "looper"):
        pid = system.procs[name].pid
        assert len([n for n in shm_names(system.run_id) if f"_{pid}_" in n]) <= 4, name


def test_a_frame_returned_to_its_owner_is_not_copied(system: ActorSystem) -> None:
    from tests.actors.workers import Looper

    system.spawn(Echo, "echo")
    looper = system.spawn(Looper, "looper")
    assert looper.ask(["echo", 10], timeout=60).get() == 9
    # The echo returned each frame it was sent: it went back as a handle to the
    # looper's own segment, so the echo never wrote a segment of its own.
    echo_pid = system.procs["echo"].pid
    assert [n for n in shm_names(system.run_id) if f"_{echo_pid}_" in n] == []


def test_a_message_handled_before_a_clean_stop_is_not_handled_again_when_resent(system: ActorSystem) -> None:
    # An actor that stops right after a tell can take that tell's ACK down with its
    # connection; the sender then re-sends it to the next incarnation (at-least-once).
    # The mailbox's table of handled sequence numbers, kept across a clean stop, acks it instead.
    c = system.spawn(Counter, "c")
    info = system.procs["c"]
    s = zmq.Context.instance().socket(zmq.DEALER)
    s.setsockopt(zmq.LINGER, 0)
    s.setsockopt(zmq.ROUTING_ID, f"{os.getpid()}.9.9".encode())
    s.setsockopt(zmq.RCVTIMEO, 5000)

    def tell_and_wait_ack(*frames: tuple[int, str]) -> None:
        s.connect(system.rt.endpoint("c"))
        for seq, body in frames:
            s.send(msgpack.packb([wire.TELL, seq, body]))
        while msgpack.unpackb(s.recv()) != [wire.ACK, frames[-1][0]]:
            pass
        s.disconnect(system.rt.endpoint("c"))

    try:
        tell_and_wait_ack((1, "x"), (2, "y"))
        assert c.ask("seen", timeout=5).get() == ["x", "y"]
        system.stop("c", unregister=False)
        system.wait_ready(system.start_process(info.spec), 10)
        tell_and_wait_ack((2, "y"), (3, "z"))  # "y" again, as after a lost ACK
        assert c.ask("seen", timeout=5).get() == ["z"]
    finally:
        s.close()
