"""Nothing lost: every told message is processed or dead-lettered with a reason."""

from __future__ import annotations

import contextlib
import os
import signal
from typing import Any

import msgpack
import pytest

from actors import ActorSystem
from supervisor import ChildSpec, SupervisorSpec, start_supervisor
from tests.supervisor.conftest import EventLog, ask, read_lines, wait_until
from tests.supervisor.workers import BurstSender, DiesWhenDecoded, Recorder


def dead_letters(system: ActorSystem) -> list[dict]:
    path = os.path.join(system.run_dir, "deadletters.log")
    if not os.path.exists(path):
        return []
    with open(path, "rb") as f:
        return list(msgpack.Unpacker(f))


def kill_one_incarnation(sup: Any, events: EventLog, child: str) -> int:
    """SIGKILL a running incarnation of ``child`` and return its pid once its crash says ``killed``.

    An incarnation can be ending already (a poison message) when the signal lands: its crash
    then has another reason, and the next incarnation is the one to kill.
    """
    while True:
        pid = wait_until(lambda: isinstance(p := next(c.pid for c in sup.which_children() if c.id == child), int)
                         and p, 10, "a running incarnation")
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
        if events.wait("crashed", child, pid=pid, timeout=10)["reason"] == "killed":
            return pid


def test_a_thousand_messages_through_five_sigkills(system: ActorSystem, events: EventLog, tmp_path) -> None:
    path = str(tmp_path / "processed")
    sup = start_supervisor(system, SupervisorSpec(intensity=20, period=60, children=[
        ChildSpec("rec", (Recorder, (path, 0.0005)), poison_limit=3)]))
    sent = [f"m{i}" for i in range(999)]
    sent.insert(500, "poison")  # crashes the actor every time: must end up dead-lettered
    ref = system.ref("rec")
    for m in sent:
        ref.tell(m)
    killed: list[int] = []  # the incarnations our SIGKILLs ended
    for k in range(1, 6):  # SIGKILL it five times while it works through the stream
        wait_until(lambda k=k: len(read_lines(path)) >= 150 * k, 30, f"{150 * k} lines")
        killed.append(kill_one_incarnation(sup, events, "rec"))
    assert ref.flush(60), "some messages were never acknowledged"
    processed = read_lines(path)
    dead = dead_letters(system)
    assert [d["message"] for d in dead] == ["'poison'"]
    assert all(d["reason"] and d["actor"] == "rec" and d["kind"] == "tell" for d in dead)
    assert set(processed) | {"poison"} == set(sent)  # none vanished
    assert [e["pid"] for e in events.of("crashed", "rec") if e["reason"] == "killed"] == killed
    # The poison crashed it poison_limit times; a SIGKILL that lands while it is in flight counts too.
    assert 1 <= len([e for e in events.of("crashed", "rec") if "ValueError: poison" in e["detail"]]) <= 3
    print(f"processed {len(processed)} lines for {len(sent) - 1} messages "
          f"({len(processed) - len(set(processed))} duplicates: at-least-once)")


def test_a_poison_message_is_dead_lettered_and_the_actor_keeps_serving(system: ActorSystem, events: EventLog, tmp_path) -> None:
    path = str(tmp_path / "processed")
    start_supervisor(system, SupervisorSpec(intensity=5, period=60, children=[
        ChildSpec("rec", (Recorder, (path,)), poison_limit=3)]))
    ref = system.ref("rec")
    ref.tell("before")
    ref.tell("poison")
    ref.tell("after")
    assert ref.flush(30)
    assert ask(system, "rec") > 0
    assert read_lines(path).count("after") >= 1 and "before" in read_lines(path)
    [dead] = dead_letters(system)
    assert dead["message"] == "'poison'" and dead["reason"] == "it crashed actor 'rec' 3 times"
    assert len(events.of("crashed", "rec")) == 3
    assert all("ValueError: poison" in e["detail"] for e in events.of("crashed", "rec"))


def test_a_frame_that_kills_its_decoder_counts_towards_the_poison_limit(system: ActorSystem, events: EventLog, tmp_path) -> None:
    # The journal takes a message before its frame is decoded: a frame that crashes the decoder is
    # dead-lettered, undecoded, at the poison limit, not re-sent to each new incarnation until the
    # supervisor gives up.
    path = str(tmp_path / "processed")
    start_supervisor(system, SupervisorSpec(intensity=5, period=60, children=[
        ChildSpec("rec", (Recorder, (path,)), poison_limit=3)]))
    ref = system.ref("rec")
    ref.tell("before")
    ref.tell(DiesWhenDecoded(os.getpid()))
    ref.tell("after")
    assert ref.flush(30)
    assert ask(system, "rec") > 0
    assert "after" in read_lines(path)
    [dead] = dead_letters(system)
    assert dead["reason"] == "it crashed actor 'rec' 3 times" and "not decoded: decoding it crashed" in dead["message"]
    assert dead["kind"] == "tell"
    assert len(events.of("crashed", "rec")) == 3


@pytest.mark.parametrize(("batch", "pause"), [(100, 0.4), (25, 0.06)])
def test_tells_from_inside_a_long_handler_survive_the_receivers_restarts(
    system: ActorSystem, events: EventLog, tmp_path: Any, batch: int, pause: float
) -> None:
    # The sender never returns to its loop while it tells, so only the send path itself can
    # notice that the receiver restarted: nothing may overtake the backlog or be acked unseen.
    path = str(tmp_path / "processed")
    n = 10 * batch
    sup = start_supervisor(system, SupervisorSpec(intensity=20, period=60, children=[
        ChildSpec("rec", (Recorder, (path, 0.002))), ChildSpec("sender", BurstSender)]))
    fut = system.ref("sender").ask(["rec", n, batch, pause], timeout=60)
    for k in range(1, 4):
        wait_until(lambda k=k: len(read_lines(path)) >= k * n // 4, 30, f"{k * n // 4} handled")
        kill_one_incarnation(sup, events, "rec")
    assert fut.get() == n
    wait_until(lambda: len(set(read_lines(path))) >= n, 30, "every number handled")
    seen = [int(x) for x in read_lines(path)]
    assert set(seen) == set(range(n)), f"lost: {sorted(set(range(n)) - set(seen))[:20]}"
    first = list(dict.fromkeys(seen))  # first-seen order: re-deliveries may repeat, never reorder
    assert first == sorted(first), f"out of order near {next(a for a, b in zip(first, first[1:], strict=False) if b < a)}"
