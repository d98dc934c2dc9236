"""The root-side hub of a run's supervision tree.

One :class:`Tree` per :class:`~actors.ActorSystem`: it listens to the
system's exit and ready notes and routes them to the incarnation they
belong to, owns the child names (unique in a run: an actor's name is its
mailbox address), the root-side handles on the actors' journals, the
event stream and the resource monitor. Everything here runs on the root
IO thread.

Example::

    tree = Tree.of(system)
    tree.events.listeners.append(print)
"""

from __future__ import annotations

import contextlib
import os
from typing import TYPE_CHECKING, Any

from actors import ActorSystem
from actors.journal import Journal
from actors.runtime import registry_path
from actors.system import ProcessInfo
from supervisor.errors import SupervisorError
from supervisor.events import Events
from supervisor.health import ResourceMonitor
from supervisor.rootio import on_root

if TYPE_CHECKING:
    from supervisor.procs import ActorProcess
    from supervisor.spec import ChildSpec
    from supervisor.standby import Standby
    from supervisor.supervisor import Supervisor

__all__ = ["Tree"]

_trees: dict[int, Tree] = {}


class Tree:
    """Shared state of the supervisors of one actor system."""

    def __init__(self, system: ActorSystem) -> None:
        self.system = system
        self.loop = system.loop
        self.events = Events(system)
        self.monitor = ResourceMonitor(self)
        self.procs: dict[str, ActorProcess] = {}  # live actor incarnations by name
        self.standbys: dict[str, Standby] = {}  # warm standbys by child name (supervisor.standby)
        self.names: dict[str, str] = {}  # child name -> path of the supervisor that has it
        self.registered: set[str] = set()  # actor names this tree put in the registry
        self.journals: dict[str, Journal] = {}
        self.roots: list[Supervisor] = []
        self.closed = False
        on_root(system, self._install)

    @classmethod
    def of(cls, system: ActorSystem) -> Tree:
        """The tree of ``system`` (created on first use)."""
        tree = _trees.get(id(system))
        if tree is None or tree.system is not system or tree.closed:
            tree = _trees[id(system)] = cls(system)
        return tree

    def _install(self) -> None:
        self.system.exit_listeners.append(self._on_exit)
        self.system.event_listeners.append(self._on_note)

    def _on_exit(self, info: ProcessInfo) -> None:
        proc = self.procs.get(info.name)
        if proc is not None:
            proc.on_exit(info)
        standby = self.standbys.get(info.name)
        if standby is not None:
            standby.on_exit(info)

    def _on_note(self, msg: list[Any]) -> None:
        try:
            kind, name, pid = str(msg[0]), str(msg[1]), int(msg[2])
        except (IndexError, TypeError, ValueError):
            return
        if kind == "standby":
            standby = self.standbys.get(name)
            if standby is not None:
                standby.on_note(kind, pid)
            return
        proc = self.procs.get(name)
        if proc is not None:
            proc.on_note(kind, pid, list(msg[3:]))

    # -- warm standbys (supervisor.standby) ----------------------------------
    def keep_standby(self, spec: ChildSpec, path: str) -> None:
        """Make sure child ``spec.id`` has a standby alive or on its way."""
        from supervisor.standby import Standby

        standby = self.standbys.get(spec.id)
        if standby is None or standby.stopped or standby.spec is not spec:
            if standby is not None:
                standby.stop()
            standby = self.standbys[spec.id] = Standby(self, spec, path)
        standby.prepare()

    def drop_standby(self, name: str) -> None:
        """Kill child ``name``'s standby, if it has one (the child stops)."""
        standby = self.standbys.pop(name, None)
        if standby is not None:
            standby.stop()

    # -- names --------------------------------------------------------------
    def claim(self, name: str, path: str, kind: str) -> None:
        """Reserve ``name`` for a child of the supervisor at ``path``."""
        owner = self.names.get(name)
        if owner is not None:
            raise SupervisorError("already_present", f"a child named {name!r} already exists (in {owner}); names are unique in a run")
        taken = name in self.system.procs or name in self.system.attached
        taken = taken or os.path.exists(registry_path(self.system.run_dir, name))
        if taken and name not in self.registered:
            raise SupervisorError("already_present", f"an actor named {name!r} already exists in this run; pick another child id")
        self.names[name] = path
        if kind == "actor" and name not in self.registered:
            self.system.rt.register(name, {"endpoint": self.system.rt.endpoint(name), "kind": "process"})
            self.registered.add(name)

    def release(self, name: str) -> None:
        """The supervisor holding ``name`` ended; a new incarnation of it may claim it again."""
        self.names.pop(name, None)

    def forget(self, name: str) -> None:
        """The child was deleted: drop its registry entry, journal and snapshot."""
        self.release(name)
        if name in self.registered:
            self.registered.discard(name)
            self.system.rt.unregister(name)
            info = self.system.procs.get(name)
            if info is not None and info.exited.is_set():
                del self.system.procs[name]  # our record of its last process: the name is free
        j = self.journals.pop(name, None)
        if j is not None:
            j.close()
        for suffix in (".journal", ".snap"):
            with contextlib.suppress(FileNotFoundError):
                os.unlink(os.path.join(self.system.run_dir, name + suffix))

    def journal(self, name: str) -> Journal:
        """The root's handle on actor ``name``'s journal (heartbeat, lifecycle state)."""
        j = self.journals.get(name)
        if j is None:
            j = self.journals[name] = Journal(os.path.join(self.system.run_dir, f"{name}.journal"))
        return j

    def close(self) -> None:
        """Detach from the system (after the trees have stopped)."""
        if self.closed:
            return
        self.closed = True

        def detach() -> None:
            with contextlib.suppress(ValueError):
                self.system.exit_listeners.remove(self._on_exit)
            with contextlib.suppress(ValueError):
                self.system.event_listeners.remove(self._on_note)
            self.monitor.close()
            self.events.close()
            for j in self.journals.values():
                j.close()
            self.journals.clear()

        on_root(self.system, detach)
        if _trees.get(id(self.system)) is self:
            del _trees[id(self.system)]
