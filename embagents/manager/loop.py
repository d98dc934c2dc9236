"""The manager: a fixed-rate main loop over handlers and a shared state.

For users who think in main loops (the ROS Base style): the loop waits for
its handshake rules, then ticks at ``rate_hz``, running every handler in
registration order on each tick. Deadlines are absolute (tick *n* is due at
``start + n / rate_hz``), so the rate does not drift; a tick that overran is
followed at once by the next, with whole missed periods skipped (the rule of
:mod:`embagents.realtime`, shared with components' rate triggers); between ticks the loop
sleeps on an event, so it costs no CPU and :meth:`Manager.stop` wakes it at
once from any thread or a signal handler.

Example::

    >>> manager = Manager(rate_hz=100)
    >>> @manager.add_handler
    ... def count(state, tick):
    ...     state.update(last=tick)
    >>> manager.run(max_ticks=3)
    3
    >>> manager.state.last, manager.tick
    (3, 3)
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from types import TracebackType
from typing import Any, Literal, TypeVar

import pykka

from embagents.manager.agents import Agent
from embagents.manager.attached import Attachments, R
from embagents.manager.handler import Handler, as_handler
from embagents.manager.handshake import HandshakeRule, wait_for_handshake
from embagents.manager.nodes import Node
from embagents.manager.state import State
from embagents.realtime import next_deadline

__all__ = ["ErrorPolicy", "Manager", "RestartPolicy"]

ErrorPolicy = Literal["log", "raise", "crash", "stop"]
RestartPolicy = Literal["resume", "initial"]
H = TypeVar("H", bound="Handler | Callable[[State, int], object]")

#: Seconds between log lines for a handler that keeps failing (after its first traceback).
REPEAT_LOG_INTERVAL = 5.0


class Manager:
    """A fixed-rate loop; see the module docstring.

    ``handshake`` rules must all hold before tick 1 (checked at the loop
    rate; :class:`~embagents.manager.handshake.HandshakeTimeout` after
    ``handshake_timeout`` seconds, None waits forever). With
    ``log_rate_every`` set, the achieved rate and overruns are logged that
    often to ``embagents.manager.<name>``. ``on_handler_error`` says what a
    handler exception does: ``"log"`` it and go on, ``"raise"`` it out of
    :meth:`run` (after shutdown; under a supervisor ``"crash"``, its alias,
    crashes the manager's actor so that the supervisor restarts it), or log it
    and ``"stop"`` the loop.

    In a System (``System(managers=[manager])``, run by ``embagents
    supervise``) the manager is a supervised actor: ``nodes`` reach the
    system's topics, ``agents`` run attached or isolated, ``hang_timeout``
    is its heartbeat deadline (a tick longer than that is a hang, killed and
    restarted), and ``on_restart`` says whether a restarted manager
    ``"resume"``s its state machines, shared state and tick counter from its
    snapshot or starts from the ``"initial"`` state.
    """

    def __init__(
        self,
        rate_hz: float,
        *,
        handshake: Sequence[HandshakeRule] = (),
        handshake_timeout: float | None = 30.0,
        log_rate_every: float | None = None,
        on_handler_error: ErrorPolicy = "log",
        name: str = "manager",
        handlers: Sequence[Handler | Callable[[State, int], object]] = (),
        nodes: Sequence[Node] = (),
        agents: Sequence[Agent] = (),
        on_restart: RestartPolicy = "resume",
        hang_timeout: float = 5.0,
    ) -> None:
        try:
            rate = float(rate_hz)
        except (TypeError, ValueError):
            rate = math.nan
        if not (math.isfinite(rate) and rate > 0):
            raise ValueError(f"rate_hz must be a positive number (ticks per second), got {rate_hz!r}")
        for label, value in [
            ("handshake_timeout", handshake_timeout),
            ("log_rate_every", log_rate_every),
        ]:
            if value is not None and not value > 0:
                raise ValueError(f"{label} must be positive seconds or None, got {value!r}")
        if on_handler_error not in ("log", "raise", "crash", "stop"):
            raise ValueError(
                f"on_handler_error must be 'log', 'raise' (alias 'crash') or 'stop', got {on_handler_error!r}"
            )
        if on_restart not in ("resume", "initial"):
            raise ValueError(f"on_restart must be 'resume' or 'initial', got {on_restart!r}")
        if not (isinstance(hang_timeout, (int, float)) and hang_timeout > 0):
            raise ValueError(f"hang_timeout must be positive seconds, got {hang_timeout!r}")
        for rule in handshake:
            if not isinstance(rule, HandshakeRule):
                raise TypeError(f"handshake rules must be HandshakeRule instances, got {rule!r}")
        self.name = name
        self.rate_hz = rate
        self.period = 1.0 / self.rate_hz
        self.handshake = tuple(handshake)
        self.handshake_timeout = handshake_timeout
        self.log_rate_every = log_rate_every
        self.on_handler_error: ErrorPolicy = on_handler_error
        self.logger = logging.getLogger(f"embagents.manager.{name}")
        self.state = State()
        #: Number of the current (or last) tick; 0 before the first.
        self.tick = 0
        #: Ticks whose handlers finished after the next tick was due.
        self.overruns = 0
        #: Rate achieved over the last logging window (needs ``log_rate_every``).
        self.achieved_rate: float | None = None
        self._handlers: list[Handler] = []
        self._started: list[Handler] = []
        self._attachments = Attachments(self.logger)
        self._failures: dict[int, tuple[type[BaseException], int, float]] = {}
        self._wake = threading.Event()
        self._stop_requested = False
        self._sleeping = False
        self._loop_ident: int | None = None
        self._lifecycle_lock = threading.Lock()
        self._running = False
        self._closed = False
        self._finished = threading.Event()
        self._thread: threading.Thread | None = None
        self._thread_error: BaseException | None = None
        self.on_restart: RestartPolicy = on_restart
        self.hang_timeout = float(hang_timeout)
        self._nodes: dict[str, Node] = {}
        self._agents: dict[str, Agent] = {}
        self._agents_started: list[Agent] = []
        for h in handlers:
            self.add_handler(h)
        for node in nodes:
            self.add_node(node)
        for agent in agents:
            self.add_agent(agent)

    # Building ------------------------------------------------------------

    def add_handler(self, handler: H) -> H:
        """Run ``handler`` every tick, after those added before it.

        Takes a :class:`Handler` or a plain ``fn(state, tick)``; returns it
        unchanged, so it also works as a decorator.
        """
        with self._lifecycle_lock:
            if self._running or self._closed:
                raise RuntimeError(f"manager {self.name!r}: add handlers before run()")
            self._handlers.append(as_handler(handler))
        return handler

    def add_node(self, node: Node) -> Node:
        """Add a :class:`~embagents.manager.nodes.Node` (bound to topics when run in a System)."""
        if not isinstance(node, Node):
            raise TypeError(f"manager {self.name!r}: expected a Node, got {node!r}")
        if node.name in self._nodes:
            raise ValueError(f"manager {self.name!r} already has a node named {node.name!r}")
        self._nodes[node.name] = node
        return node

    def add_agent(self, agent: Agent) -> Agent:
        """Add an :class:`~embagents.manager.agents.Agent`; it starts with the loop."""
        if not isinstance(agent, Agent):
            raise TypeError(f"manager {self.name!r}: expected an Agent, got {agent!r}")
        if agent.name in self._agents:
            raise ValueError(f"manager {self.name!r} already has an agent named {agent.name!r}")
        agent.actor_name = f"{self.name}.{agent.name}"
        self._agents[agent.name] = agent
        return agent

    @property
    def nodes(self) -> tuple[Node, ...]:
        return tuple(self._nodes.values())

    @property
    def agents(self) -> tuple[Agent, ...]:
        return tuple(self._agents.values())

    def agent(self, name: str) -> Agent:
        """The agent called ``name``."""
        try:
            return self._agents[name]
        except KeyError:
            raise KeyError(f"manager {self.name!r} has no agent {name!r}; agents: "
                           f"{', '.join(self._agents) or 'none'}") from None

    @property
    def handlers(self) -> tuple[Handler, ...]:
        """The handlers, in the order they run each tick."""
        return tuple(self._handlers)

    def attach(self, resource: R, *, name: str | None = None) -> R:
        """Start ``resource`` (anything with ``start()``/``stop()``) now; stop it at shutdown."""
        return self._attachments.attach(resource, name=name)

    def attach_actor(
        self, actor_class: type[pykka.Actor], *args: Any, **kwargs: Any
    ) -> pykka.ActorRef[Any]:
        """Start a pykka actor in this process (a thread); it stops at shutdown.

        Returns its ref. A ``stop_timeout`` keyword (default 5 s) bounds the wait
        for its mailbox to drain at shutdown; other arguments go to the actor.
        """
        return self._attachments.attach_actor(actor_class, *args, **kwargs)

    @property
    def attached(self) -> tuple[str, ...]:
        """Names of attached resources, in attachment (= start) order."""
        return self._attachments.names

    def on_message(self, key: str) -> Callable[[Any], None]:
        """A callback that stores each message it gets in ``state[key]``.

        Hand it to a topic subscription (from any thread); it also marks
        ``state.received[key]``, which ``HandshakeRule.message_received`` waits for.
        """

        def store(message: Any) -> None:
            self.state.receive(key, message)

        store.__name__ = f"store_{key}"
        return store

    # Running -------------------------------------------------------------

    def run(self, max_ticks: int | None = None) -> int:
        """Handshake, then tick until :meth:`stop` or ``max_ticks``; returns ticks run.

        Shuts the manager down on the way out (handlers' ``on_stop``, then
        attached resources in reverse order), whatever ended the loop.
        """
        self._claim(max_ticks)
        return self._run(max_ticks)

    def run_in_thread(self, max_ticks: int | None = None) -> threading.Thread:
        """Start :meth:`run` in a new thread; :meth:`join` it to get its outcome."""
        # Claimed here, not in the thread, so that a stop() or shutdown()
        # right after this call already sees a running manager.
        self._claim(max_ticks)

        def target() -> None:
            try:
                self._run(max_ticks)
            except BaseException as exc:
                self._thread_error = exc
                self.logger.exception("manager loop failed")

        self._thread = threading.Thread(target=target, name=f"embagents.manager.{self.name}")
        self._thread.start()
        return self._thread

    def _claim(self, max_ticks: int | None) -> None:
        if max_ticks is not None and max_ticks < 0:
            raise ValueError(f"max_ticks must be >= 0 or None, got {max_ticks!r}")
        with self._lifecycle_lock:
            if self._running:
                raise RuntimeError(f"manager {self.name!r} is already running")
            if self._closed:
                raise RuntimeError(f"manager {self.name!r} has shut down; create a new one")
            self._running = True

    def _run(self, max_ticks: int | None) -> int:
        self._loop_ident = threading.get_ident()
        try:
            isolated = [a.name for a in self._agents.values() if a.isolated]
            if isolated:
                raise RuntimeError(
                    f"manager {self.name!r}: isolated agents ({', '.join(isolated)}) are actor processes; run the "
                    "manager in a System (System(managers=[...]), `embagents supervise system.py`) or attach them"
                )
            self.start_agents()
            if not self._wait_for_handshake():
                return 0
            self.start_handlers()
            return self._spin(max_ticks)
        finally:
            try:
                self._close()
            finally:
                self._running = False
                self._loop_ident = None
                self._finished.set()

    def join(self, timeout: float | None = None) -> None:
        """Wait for the :meth:`run_in_thread` loop; re-raise what ended it, if anything."""
        if self._thread is None:
            raise RuntimeError(f"manager {self.name!r} has no loop thread")
        self._thread.join(timeout)
        if self._thread.is_alive():
            raise TimeoutError(f"manager {self.name!r} still running after {timeout} s")
        if self._thread_error is not None:
            raise self._thread_error

    def stop(self) -> None:
        """Ask the loop to end after the current tick; returns at once.

        Safe from any thread and from signal handlers. A stopped manager
        does not run again.
        """
        self._stop_requested = True
        if threading.get_ident() != self._loop_ident:
            self._wake.set()
        elif self._sleeping:
            # A signal handler that interrupted the loop's own wait, maybe
            # while it held the event's internal lock: setting the event here
            # could deadlock, so a helper thread does it.
            threading.Thread(target=self._wake.set, daemon=True).start()
        # else: the loop thread between waits; it checks the flag before sleeping.

    def shutdown(self) -> None:
        """End the loop (waiting for it), then release everything, newest first.

        Handlers' ``on_stop`` run in reverse registration order, then attached
        resources stop in reverse attachment order. Idempotent; errors are
        logged so that every resource is still released.
        """
        if self._running:
            # The loop releases everything on its way out; from inside a
            # handler we can only ask it to stop.
            self.stop()
            if threading.get_ident() != self._loop_ident:
                self._finished.wait()
            return
        self._close()

    def _close(self) -> None:
        with self._lifecycle_lock:
            if self._closed:
                return
            self._closed = True
        for handler in reversed(self._started):
            try:
                handler.on_stop(self.state)
            except Exception:
                self.logger.exception("handler %r failed in on_stop", handler.name)
        self._started.clear()
        for agent in reversed(self._agents_started):
            try:
                agent.stop()
            except Exception:
                self.logger.exception("agent %r failed to stop", agent.name)
        self._agents_started.clear()
        self._attachments.close()

    def __enter__(self) -> Manager:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.shutdown()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join()

    # The loop ------------------------------------------------------------

    def _sleep(self, seconds: float) -> bool:
        """Wait up to ``seconds`` unless stopped; True if a stop was requested."""
        # Flag first, check second: a stop() landing in between then wakes us.
        self._sleeping = True
        try:
            if seconds > 0 and not self._stop_requested:
                self._wake.wait(seconds)
        finally:
            self._sleeping = False
        return self._stop_requested

    def _wait_for_handshake(self) -> bool:
        if self._stop_requested:
            return False
        return wait_for_handshake(
            self.handshake,
            self.state,
            period=self.period,
            timeout=self.handshake_timeout,
            sleep=self._sleep,
            logger=self.logger,
        )

    def _spin(self, max_ticks: int | None) -> int:
        handlers = tuple(self._handlers)
        ticks = 0
        deadline = window_start = time.monotonic()
        window_ticks = window_overruns = 0
        while not self._stop_requested and (max_ticks is None or ticks < max_ticks):
            if self.log_rate_every is not None:
                # Measured from tick start to tick start: n ticks, n periods.
                begun = time.monotonic()
                if begun - window_start >= self.log_rate_every:
                    window = begun - window_start
                    self.log_rate(window_ticks / window, window_overruns, window)
                    window_start, window_ticks, window_overruns = begun, 0, 0
                window_ticks += 1
            ticks += 1
            if not self.tick_once(handlers):
                break
            now = time.monotonic()
            deadline, overran = next_deadline(deadline, self.period, now)  # the rate rule: embagents.realtime
            if overran:
                self.overruns += 1
                window_overruns += 1
            if max_ticks is not None and ticks >= max_ticks:
                break
            self._sleep(deadline - now)
        if self._stop_requested:
            self.logger.info("stopped after tick %d", self.tick)
        return ticks

    # Stepping (used by run() and by the manager's actor) -------------------

    def start_agents(self) -> None:
        """Start every agent (attached ones build their object here, in this process)."""
        for agent in self._agents.values():
            agent.start()
            self._agents_started.append(agent)

    def start_handlers(self) -> None:
        """Handlers' ``on_start``, once, after the handshake."""
        for handler in self._handlers:
            if handler not in self._started:
                handler.on_start(self.state)
                self._started.append(handler)

    def tick_once(self, handlers: tuple[Handler, ...] | None = None) -> bool:
        """Count a tick and run every handler once; False if the loop must end now."""
        self.tick += 1
        return self._run_handlers(self.handlers if handlers is None else handlers)

    def snapshot(self) -> dict[str, Any]:
        """What a restarted manager resumes from: the tick, the state's kept values, each handler's state."""
        return {
            "tick": self.tick,
            "state": self.state.kept(),
            "handlers": [[h.name, h.snapshot()] for h in self._handlers],
        }

    def restore(self, saved: dict[str, Any]) -> None:
        """Resume from :meth:`snapshot` (``on_restart="resume"``) and say so in the log."""
        if self.on_restart == "initial":
            self.logger.info("restarted: starting from the initial state (on_restart='initial'; the snapshot at "
                             "tick %s is ignored)", saved.get("tick"))
            return
        self.tick = int(saved.get("tick") or 0)
        self.state.update(saved.get("state") or {})
        by_name = {h.name: h for h in self._handlers}
        resumed = []
        for name, snap in saved.get("handlers") or []:
            handler = by_name.get(name)
            if handler is not None and snap is not None:
                phrase = handler.restore(snap)
                if phrase:
                    resumed.append(f"handler {name!r} {phrase}")
        self.logger.warning("restarted: resuming at tick %d%s", self.tick,
                            (": " + ", ".join(resumed)) if resumed else "")

    def _run_handlers(self, handlers: tuple[Handler, ...]) -> bool:
        """One tick over all handlers; False if the loop must end now."""
        for index, handler in enumerate(handlers):
            try:
                handler.on_tick(self.state, self.tick)
            except Exception as exc:
                if self.on_handler_error in ("raise", "crash"):
                    if hasattr(exc, "add_note"):  # Python 3.11+
                        exc.add_note(f"in handler {handler.name!r} on tick {self.tick}")
                    raise
                self._log_failure(index, handler, exc)
                if self.on_handler_error == "stop":
                    self.logger.error(
                        "stopping: handler %r failed (on_handler_error='stop')", handler.name
                    )
                    self._stop_requested = True
                    return False
            else:
                if index in self._failures:
                    _, count, _ = self._failures.pop(index)
                    self.logger.info(
                        "handler %r recovered after %d failed ticks", handler.name, count
                    )
        return True

    def _log_failure(self, index: int, handler: Handler, exc: Exception) -> None:
        # The first failure gets a traceback; a handler failing on every tick
        # is then summarised now and then instead of flooding the log for days.
        now = time.monotonic()
        previous = self._failures.get(index)
        if previous is None or previous[0] is not type(exc):
            self.logger.exception("handler %r failed on tick %d", handler.name, self.tick)
            self._failures[index] = (type(exc), 1, now)
            return
        kind, count, logged = previous
        if now - logged >= REPEAT_LOG_INTERVAL:
            self.logger.error(
                "handler %r still failing on tick %d: %s: %s (%d ticks in a row)",
                handler.name, self.tick, kind.__name__, exc, count + 1,
            )
            logged = now
        self._failures[index] = (kind, count + 1, logged)

    def log_rate(self, rate: float, overruns: int, window: float) -> None:
        """Log the rate achieved over the last ``window`` s (a warning if ticks overran)."""
        self.achieved_rate = rate
        level = logging.WARNING if overruns else logging.INFO
        self.logger.log(
            level, "%.2f Hz (target %g Hz), %d overruns in the last %.1f s",
            rate, self.rate_hz, overruns, window,
        )

    def __repr__(self) -> str:
        status = "running" if self._running else "closed" if self._closed else "ready"
        return f"<Manager {self.name!r} {self.rate_hz:g} Hz, {status}, tick {self.tick}>"
