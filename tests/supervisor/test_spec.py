"""Child and supervisor specs: defaults and clear errors at declaration time."""

from __future__ import annotations

import pytest

from actors import Actor
from supervisor import Backoff, ChildSpec, Command, SupervisorSpec
from supervisor.spec import ActorStart
from tests.supervisor.workers import Echo


def test_defaults_follow_otp() -> None:
    w = ChildSpec("w", Echo)
    assert (w.restart, w.shutdown, w.type, w.kind) == ("permanent", 5.0, "worker", "actor")
    assert w.start == ActorStart(Echo, (), {})
    s = ChildSpec("s", SupervisorSpec())
    assert (s.shutdown, s.type, s.kind, s.module) == ("infinity", "supervisor", "supervisor", "supervisor")
    c = ChildSpec("c", Command(["socat", "-"]))
    assert (c.kind, c.module) == ("command", "socat")
    assert SupervisorSpec().intensity == 1 and SupervisorSpec().period == 5.0


def test_start_forms() -> None:
    assert ChildSpec("a", (Echo, ["log"])).start == ActorStart(Echo, ("log",), {})
    assert ChildSpec("a", (Echo, (), {"log": "x"})).start.kwargs == {"log": "x"}


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"restart": "sometimes"}, "restart must be one of"),
        ({"shutdown": "soon"}, "shutdown is seconds"),
        ({"shutdown": -1}, "shutdown must be >= 0"),
        ({"heartbeat": 0}, "heartbeat must be > 0"),
        ({"lifecycle": "running"}, "lifecycle must be one of"),
        ({"type": "supervisor"}, "type must be 'supervisor' for a SupervisorSpec"),
        ({"backoff": 3}, "backoff must be a supervisor.Backoff"),
    ],
)
def test_bad_child_specs(kwargs: dict, match: str) -> None:
    with pytest.raises((ValueError, TypeError), match=match):
        ChildSpec("a", Echo, **kwargs)


def test_bad_starts() -> None:
    class Local(Actor):
        pass

    with pytest.raises(TypeError, match="defined inside a function"):
        ChildSpec("a", Local)
    with pytest.raises(TypeError, match="not an actors.Actor subclass"):
        ChildSpec("a", int)
    with pytest.raises(TypeError, match="start must be"):
        ChildSpec("a", "Echo")
    with pytest.raises(TypeError, match="non-empty list of strings"):
        Command("socat -")
    with pytest.raises(ValueError, match="invalid name"):
        ChildSpec("a b", Echo)
    with pytest.raises(ValueError, match="needs an actor child"):
        ChildSpec("c", Command(["x"]), heartbeat=1.0)


def test_bad_supervisor_specs() -> None:
    with pytest.raises(ValueError, match="strategy must be one of"):
        SupervisorSpec(strategy="all_for_none")
    with pytest.raises(ValueError, match="duplicate child ids: a"):
        SupervisorSpec(children=[ChildSpec("a", Echo), ChildSpec("a", Echo)])
    with pytest.raises(ValueError, match="exactly one child spec"):
        SupervisorSpec(strategy="simple_one_for_one", children=[])
    with pytest.raises(ValueError, match="intensity must be an integer"):
        SupervisorSpec(intensity=-1)
    with pytest.raises(ValueError, match="period must be > 0"):
        SupervisorSpec(period=0)


def test_with_args_for_dynamic_children() -> None:
    t = ChildSpec("w", (Echo, ("a",)), backoff=Backoff())
    d = t.with_args("w.1", ["b"])
    assert d.id == "w.1" and d.start.args == ("a", "b") and d.backoff == t.backoff
    assert ChildSpec("c", Command(["sleep"])).with_args("c.1", [5]).start.argv == ("sleep", "5")
