"""The fork server refuses what is not one of the root's commands, and goes on serving."""

from __future__ import annotations

import os

import msgpack
import pytest

from actors import ActorSystem
from tests.actors.workers import Echo, FdProbe


@pytest.mark.parametrize("bad", [b"\xc1", msgpack.packb(7), msgpack.packb([]), msgpack.packb(["spawn", 1]),
                                 msgpack.packb(["spawn", 1, "not a spec"]), msgpack.packb(["kill", 0, 9]),
                                 msgpack.packb(["kill", "1", 9]), msgpack.packb(["dance"])])
def test_a_bad_command_is_dropped_and_the_fork_server_goes_on(system: ActorSystem, bad: bytes) -> None:
    system.forkserver.sock.send(bad)
    ref = system.spawn(Echo, "after")
    assert ref.ask("hi", timeout=10).get() == "hi"


def test_actors_keep_devnull_handles_opened_before_the_fork_server_and_nothing_else() -> None:
    # llama_cpp opens /dev/null at import and redirects its C output through it: an actor
    # loading a model must find that fd open, while a pipe of the root's must not leak in.
    devnull = open(os.devnull, "w")  # noqa: SIM115
    r, w = os.pipe()
    try:
        with ActorSystem() as system:
            ref = system.spawn(FdProbe, "probe")
            ours = [[(st := os.fstat(fd)).st_dev, st.st_ino] for fd in (devnull.fileno(), r, w)]
            theirs = ref.ask([devnull.fileno(), r, w], timeout=10).get()
            assert theirs[0] == ours[0]  # the same /dev/null handle
            assert theirs[1] != ours[1] and theirs[2] != ours[2]  # the pipe is not inherited (a number may be reused)
    finally:
        devnull.close()
        os.close(r)
        os.close(w)
