"""The link's socket helpers."""

from __future__ import annotations

import zmq
from zmq.utils.monitor import recv_monitor_message

from actors.link import monitor_socket


def test_a_monitor_never_collides_with_a_stale_monitor_on_a_reused_fd() -> None:
    # A socket collected by the GC keeps its monitor bound at "inproc://monitor.s-<fd>" until
    # libzmq's reaper runs; a new socket on the same fd then could not be monitored at all.
    ctx = zmq.Context()
    opened: list[zmq.Socket] = []

    def sock(kind: int) -> zmq.Socket:
        opened.append(ctx.socket(kind))
        opened[-1].setsockopt(zmq.LINGER, 0)
        return opened[-1]

    try:
        new, stale, listener = sock(zmq.DEALER), sock(zmq.DEALER), sock(zmq.ROUTER)
        stale.monitor(f"inproc://monitor.s-{new.FD}", zmq.EVENT_ALL)  # what the dead socket left behind
        mon = monitor_socket(new, zmq.EVENT_CONNECTED)
        opened.append(mon)
        port = listener.bind_to_random_port("tcp://127.0.0.1")
        new.connect(f"tcp://127.0.0.1:{port}")
        assert mon.poll(5000), "the monitor saw no event"
        assert recv_monitor_message(mon)["event"] == zmq.EVENT_CONNECTED
    finally:
        for s in opened:
            s.close(0)
        ctx.term()
