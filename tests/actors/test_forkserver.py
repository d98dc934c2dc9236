"""The fork server refuses what is not one of the root's commands, and goes on serving."""

from __future__ import annotations

import os
from typing import Any

import msgpack
import pykka
import pytest

from actors import ActorSystem
from tests.actors import workers
from tests.actors.workers import Echo, FdProbe, FdReuse, GcProbe


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


def test_a_root_object_dropped_in_an_actor_does_not_close_the_actors_own_fds(tmp_path: Any) -> None:
    # A file of the root's that an actor drops later (a library re-initialised after the fork lets go
    # of its handles) closes its fd number there: that number must not be one the actor uses by then.
    workers.INHERITED.append(open(tmp_path / "root-file", "w"))  # noqa: SIM115
    try:
        with ActorSystem() as system:
            assert system.spawn(FdReuse, "reuser").ask(workers.INHERITED[0].fileno(), timeout=10).get() == []
    finally:
        workers.INHERITED.pop().close()


def test_an_actors_garbage_collector_leaves_the_roots_objects_alone() -> None:
    # A full collection in an actor would otherwise walk every object the root had when it forked
    # (and copy their pages): half a second in an actor of a test runner late in a suite.
    roots = [[i] for i in range(200_000)]  # lists: tracked by the collector (a dict of ints is not)
    with ActorSystem() as system:
        frozen, tracked = system.spawn(GcProbe, "gc").ask(None, timeout=10).get()
    assert frozen > len(roots) and tracked < len(roots)


def test_a_dead_fork_server_is_reported_and_no_start_or_ask_waits_forever() -> None:
    import signal
    import time

    from actors.errors import ActorError

    with ActorSystem() as system:
        ref = system.spawn(Echo, "before")
        assert ref.ask("hi", timeout=10).get() == "hi"
        info = system.procs["before"]
        os.kill(system.forkserver.pid, signal.SIGKILL)
        assert info.exited.wait(10), "the actor's death (with its fork server) was never reported"
        assert info.exit_code == -signal.SIGKILL and "fork server" in (info.failure or ""), info.failure
        assert system.forkserver_failure is not None and "killed by signal 9" in system.forkserver_failure
        # A start now fails at once with the reason, instead of waiting for a server that is gone.
        later = system.start_process(system.make_spec(Echo, "after", (), {}))
        assert later.exited.is_set() and "start it again" in (later.failure or "")
        t0 = time.monotonic()
        with pytest.raises((ActorError, pykka.Timeout)):  # the actor is gone: no answer, in bounded time
            ref.ask("hi", timeout=2).get()
        assert time.monotonic() - t0 < 10


def test_an_io_thread_stopped_by_an_error_fails_its_callers_instead_of_hanging(tmp_path: str) -> None:
    from actors.errors import ActorError
    from actors.runtime import Runtime

    rt = Runtime(str(tmp_path), "t")
    try:
        rt.on_client(lambda: None)  # starts the IO thread

        def broken() -> None:
            raise RuntimeError("a handler bug")

        rt.client_loop().call_soon_threadsafe(broken)
        with pytest.raises(ActorError, match="IO thread of this process is gone"):
            rt.on_client(lambda: None)
    finally:
        rt.closed = True
