"""The fork server refuses what is not one of the root's commands, and goes on serving."""

from __future__ import annotations

import msgpack
import pytest

from actors import ActorSystem
from tests.actors.workers import Echo


@pytest.mark.parametrize("bad", [b"\xc1", msgpack.packb(7), msgpack.packb([]), msgpack.packb(["spawn", 1]),
                                 msgpack.packb(["spawn", 1, "not a spec"]), msgpack.packb(["kill", 0, 9]),
                                 msgpack.packb(["kill", "1", 9]), msgpack.packb(["dance"])])
def test_a_bad_command_is_dropped_and_the_fork_server_goes_on(system: ActorSystem, bad: bytes) -> None:
    system.forkserver.sock.send(bad)
    ref = system.spawn(Echo, "after")
    assert ref.ask("hi", timeout=10).get() == "hi"
