"""The journal outlives the process: heartbeat, in-flight message, crash counts."""

from __future__ import annotations

from pathlib import Path

from actors.journal import Journal


def test_a_crash_on_another_message_does_not_reset_a_poison_count(tmp_path: Path) -> None:
    j = Journal(str(tmp_path / "a.journal"))
    for seq in (7, 9, 7, 7):  # died on 7, then on 9 (an outside kill), then twice more on 7
        j.begin(b"sender", seq)
        j.close()
        j = Journal(str(tmp_path / "a.journal"))  # a new incarnation opens it again
        j.on_restart()
    assert j.crashes() == {(b"sender", 7): 3, (b"sender", 9): 1}
    j.forget_crash(b"sender", 7)
    assert j.crashes() == {(b"sender", 9): 1}
    assert j.incarnation == 4 and j.inflight() is None


def test_heartbeat_and_state_survive_reopening(tmp_path: Path) -> None:
    j = Journal(str(tmp_path / "b.journal"))
    j.beat()
    j.set_state(2)
    beat = j.last_beat()
    j.close()
    j2 = Journal(str(tmp_path / "b.journal"))
    assert j2.last_beat() == beat and j2.state() == 2


def test_a_crash_while_a_frame_was_decoded_is_told_from_one_in_its_handler(tmp_path: Path) -> None:
    j = Journal(str(tmp_path / "c.journal"))
    j.begin(b"sender", 3, decoded=False)  # died decoding message 3
    j.close()
    j = Journal(str(tmp_path / "c.journal"))
    j.on_restart()
    j.begin(b"sender", 4, decoded=False)
    j.decoded()  # died in the handler of message 4
    j.close()
    j = Journal(str(tmp_path / "c.journal"))
    j.on_restart()
    assert j.crashes() == {(b"sender", 3): 1, (b"sender", 4): 1}
    assert j.undecodable() == {(b"sender", 3)}
