"""Host extensions: their hooks run in the actor's process in the declared order; a bad one fails the start clearly."""

from __future__ import annotations

import os
from typing import Any

import pytest

from actors import Actor, ActorError, ActorRef, ActorSystem, HostExtension, extension_spec, wire


def _note(ext: HostExtension, line: str) -> None:
    with open(os.path.join(ext.host.rt.run_dir, f"{ext.host.name}.order"), "a") as f:
        f.write(line + "\n")


class Recorder(HostExtension):
    """Writes every hook call, tagged with its config's "tag", to <run_dir>/<actor>.order."""

    name = "recorder"

    def controls(self) -> dict[str, Any]:
        return {"tag": lambda: self.config["tag"]}

    def before_start(self) -> None:
        _note(self, f"{self.config['tag']}.before_start")

    def after_start(self) -> None:
        _note(self, f"{self.config['tag']}.after_start")

    def after_message(self, kind: int, ok: bool) -> None:
        kinds = {wire.TELL: "tell", wire.ASK: "ask", wire.CTRL: "ctrl"}
        _note(self, f"{self.config['tag']}.after_message {kinds[kind]} {'ok' if ok else 'raised'}")

    def state_changed(self) -> None:
        _note(self, f"{self.config['tag']}.state_changed")

    def after_stop(self) -> None:
        _note(self, f"{self.config['tag']}.after_stop")


class Noted(Actor):
    def on_start(self) -> None:
        with open(os.path.join(self.context.run_dir, f"{self.name}.order"), "a") as f:
            f.write("on_start\n")
        assert isinstance(self.context.extension("recorder"), Recorder)

    def on_receive(self, message: Any) -> Any:
        if message == "fail":
            raise ValueError("asked to fail")
        if message == "changed":
            self.context.changed()
        return message

    def on_stop(self) -> None:
        with open(os.path.join(self.context.run_dir, f"{self.name}.order"), "a") as f:
            f.write("on_stop\n")


def _start(system: ActorSystem, name: str, extensions: list[Any]) -> None:
    # What the supervisor does: register the name, then start the process from a spec.
    system.rt.register(name, {"endpoint": system.rt.endpoint(name), "kind": "process"})
    spec = system.make_spec(Noted, name, (), {}, extensions=extensions)
    system.wait_ready(system.start_process(spec), 30)


def test_hooks_run_in_the_declared_order_around_start_messages_and_stop(system: ActorSystem) -> None:
    _start(system, "n", [extension_spec(Recorder, {"tag": "a"}), extension_spec(Recorder, {"tag": "b"})])
    ref = ActorRef("n")
    assert ref.ask("hi", timeout=5).get() == "hi"
    with pytest.raises(Exception, match="asked to fail"):
        ref.ask("fail", timeout=5).get()
    ref.ask("changed", timeout=5).get()
    assert system.ctrl("n", "tag") == "b"  # controls: the later extension's command wins
    path = os.path.join(system.run_dir, "n.order")
    system.stop("n")
    with open(path) as f:
        lines = f.read().splitlines()
    assert lines == [
        "a.before_start", "b.before_start", "on_start", "a.after_start", "b.after_start",
        "a.after_message ask ok", "b.after_message ask ok",
        "a.after_message ask raised", "b.after_message ask raised",
        "a.state_changed", "b.state_changed", "a.after_message ask ok", "b.after_message ask ok",
        "a.after_message ctrl ok", "b.after_message ctrl ok",  # "tag"
        "a.after_message ctrl ok", "b.after_message ctrl ok",  # the "stop" of system.stop
        "on_stop", "b.after_stop", "a.after_stop",
    ], lines


def test_an_extension_that_is_not_one_fails_the_start_naming_it(system: ActorSystem) -> None:
    with pytest.raises(ActorError, match="not a HostExtension subclass"):
        _start(system, "bad", [["actors.actor:Actor", {}]])
    with pytest.raises(ActorError, match="cannot load host extension 'no.such:Thing'"):
        _start(system, "missing", [["no.such:Thing", {}]])


def test_extension_spec_refuses_what_a_child_could_not_load() -> None:
    class Local(HostExtension):
        pass

    with pytest.raises(TypeError, match="at module top level"):
        extension_spec(Local)
    with pytest.raises(TypeError, match="HostExtension subclass"):
        extension_spec(Noted)  # type: ignore[arg-type]
