"""Events: conditions, rising edge / once / delay; actions as plain data; fallbacks."""

from __future__ import annotations

import pytest

from actors.codec import Codec
from embagents.components import HealthStatus
from embagents.events import (
    ACTION_KINDS,
    Action,
    Event,
    Fallback,
    call,
    give_up,
    on,
    publish,
    reconfigure,
    restart,
    start,
    stop,
    switch_model_client,
)
from embagents.msgs import Detections, String, Twist
from embagents.topic import Topic

TEXT = Topic("text", String)
VEL = Topic("cmd_vel", Twist)
DETS = Topic("detections", Detections)


@pytest.mark.parametrize(
    ("cond", "msg", "expected"),
    [
        (on(VEL).field("linear.0") == 1.0, Twist(linear=(1, 0, 0)), True),
        (on(VEL).field("linear.0") != 1.0, Twist(linear=(1, 0, 0)), False),
        (on(VEL).field("linear.0") < 0.5, Twist(linear=(0.4, 0, 0)), True),
        (on(VEL).field("linear.0") <= 0.4, Twist(linear=(0.5, 0, 0)), False),
        (on(VEL).field("angular.2") > 0.1, Twist(angular=(0, 0, 0.2)), True),
        (on(VEL).field("angular.2") >= 0.3, Twist(angular=(0, 0, 0.2)), False),
    ],
)
def test_comparisons(cond, msg, expected):
    assert cond.evaluate({"cmd_vel": msg}) is expected


def test_in_and_contains():
    assert (on(TEXT).field("data").in_(["stop", "halt"])).evaluate({"text": String("halt")})
    assert not (on(TEXT).field("data").in_(["stop", "halt"])).evaluate({"text": String("go")})
    dets = Detections(boxes=[[0, 0, 1, 1]], labels=["person"], scores=[0.9])
    assert (on(DETS).field("labels").contains("person")).evaluate({"detections": dets})
    assert not (on(DETS).field("labels").contains("cat")).evaluate({"detections": dets})


def test_and_or_not():
    stop_word = on(TEXT).field("data") == "stop"
    moving = on(VEL).field("linear.0") > 0
    both = {"text": String("stop"), "cmd_vel": Twist(linear=(1, 0, 0))}
    assert (stop_word & moving).evaluate(both)
    assert not (stop_word & ~moving).evaluate(both)
    assert (~stop_word | moving).evaluate(both)
    assert not (stop_word & moving).evaluate({"text": String("stop")})  # cmd_vel not heard yet
    assert {t.name for t in (stop_word & moving).topics} == {"text", "cmd_vel"}


def test_python_boolean_operators_are_refused():
    with pytest.raises(TypeError, match="combine conditions with &"):
        _ = (on(TEXT).field("data") == "a") and (on(TEXT).field("data") == "b")


def test_unknown_field_names_topic_and_fields():
    with pytest.raises(ValueError, match="'text' carries String, which has no field 'dat'; fields: data"):
        on(TEXT).field("dat")
    with pytest.raises(TypeError, match="on\\(\\) takes a Topic"):
        on("text")


def test_uncomparable_or_missing_values_are_false_not_errors():
    assert not (on(TEXT).field("data") < 3).evaluate({"text": String("x")})
    assert not (on(VEL).field("linear.7") == 0).evaluate({"cmd_vel": Twist()})
    assert not (on(DETS).field("scores") == 0.5).evaluate({"detections": Detections(
        boxes=[[0, 0, 1, 1], [0, 0, 1, 1]], labels=["a", "b"], scores=[0.5, 0.5])})


def test_field_compared_with_another_field():
    other = Topic("limit", Twist)
    cond = on(VEL).field("linear.0") > on(other).field("linear.0")
    assert cond.evaluate({"cmd_vel": Twist(linear=(2, 0, 0)), "limit": Twist(linear=(1, 0, 0))})
    assert not cond.evaluate({"cmd_vel": Twist(linear=(2, 0, 0))})
    assert {t.name for t in cond.topics} == {"cmd_vel", "limit"}


def test_bare_field_is_truthiness():
    assert on(TEXT).field("data").evaluate({"text": String("x")})
    assert not on(TEXT).field("data").evaluate({"text": String("")})


# --- events ---------------------------------------------------------------------------


def feed(event: Event, *texts: str, **kw) -> list[bool]:
    return [event.check("text", String(t), **kw) for t in texts]


def test_rising_edge_by_default():
    ev = Event("stop", on(TEXT).field("data") == "stop")
    assert feed(ev, "stop", "stop", "go", "stop") == [True, False, False, True]


def test_level_triggered_when_on_change_is_false():
    ev = Event("stop", on(TEXT).field("data") == "stop", on_change=False)
    assert feed(ev, "stop", "stop", "go") == [True, True, False]


def test_once_fires_once_until_reset():
    ev = Event("stop", on(TEXT).field("data") == "stop", once=True)
    assert feed(ev, "stop", "go", "stop") == [True, False, False]
    ev.reset()
    assert feed(ev, "stop") == [True]


def test_keep_event_delay_debounces():
    ev = Event("stop", on(TEXT).field("data") == "stop", on_change=False, keep_event_delay=1.0)
    assert ev.check("text", String("stop"), now=10.0)
    assert not ev.check("text", String("stop"), now=10.5)
    assert ev.check("text", String("stop"), now=11.1)


def test_other_topics_are_ignored_and_do_not_change_state():
    ev = Event("stop", on(TEXT).field("data") == "stop")
    assert not ev.check("cmd_vel", Twist())
    assert feed(ev, "stop") == [True]


def test_event_validation():
    with pytest.raises(ValueError, match="non-empty str name"):
        Event("", on(TEXT).field("data") == "x")
    with pytest.raises(TypeError, match="event 'e': condition must be built with on"):
        Event("e", lambda msg: True)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="keep_event_delay"):
        Event("e", on(TEXT).field("data") == "x", keep_event_delay=-1)


def test_events_hash_by_identity():
    cond = on(TEXT).field("data") == "x"
    a, b = Event("e", cond), Event("e", cond)
    assert len({a: 1, b: 2}) == 2


# --- actions --------------------------------------------------------------------------


class Named:
    name = "nav"


def test_action_constructors_give_plain_data():
    assert start("nav") == Action("start", "nav")
    assert stop(Named()) == Action("stop", "nav")
    assert restart() == Action("restart", None)
    assert reconfigure("llm", {"temperature": 0.1}).args == {"overrides": {"temperature": 0.1}}
    assert call("llm", "reset_history").to_dict() == {
        "kind": "call", "component": "llm", "args": {"method": "reset_history", "args": [], "kwargs": {}}}
    assert call("arm", "move", 1, speed=2).args == {"method": "move", "args": [1], "kwargs": {"speed": 2}}
    assert switch_model_client("backup").args == {"client": "backup"}
    assert give_up().kind == "give_up"
    for action in (start("a"), publish(TEXT, String("hi")), call("a", "m", 1), reconfigure("a", {"x": 1})):
        assert set(action.args) <= set(ACTION_KINDS[action.kind])


def test_actions_roundtrip_through_msgpack():
    codec = Codec()
    for action in (publish(TEXT, String("hi")), reconfigure("llm", {"temperature": 0.1}), call("a", "m", 1, k=[2])):
        assert codec.decode(codec.encode(action.to_dict())[0]) == action.to_dict()


def test_action_validation():
    with pytest.raises(ValueError, match="unknown action kind 'explode'; known: start"):
        Action("explode")
    with pytest.raises(TypeError, match="topic 'text' carries String, got Twist"):
        publish(TEXT, Twist())
    with pytest.raises(ValueError, match="public method"):
        call("llm", "_private")
    with pytest.raises(TypeError, match="overrides must be a dict"):
        reconfigure("llm", ["temperature"])  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="a component or its name"):
        start(3)


# --- fallbacks ------------------------------------------------------------------------


def test_fallback_steps_then_give_up_then_reset_on_healthy():
    fb = Fallback(on_algorithm_fail=[switch_model_client("backup"), restart()], max_retries=3)
    kinds = [fb.decide(HealthStatus.ALGORITHM_FAILURE, "llm").kind for _ in range(4)]
    assert kinds == ["switch_model_client", "restart", "restart", "give_up"]
    assert fb.decide("healthy") is None
    assert fb.decide(1, "llm") == switch_model_client("backup", "llm")


def test_fallback_acts_once_per_failing_sender_and_a_switch_makes_a_new_one():
    fb = Fallback(on_algorithm_fail=[switch_model_client("backup"), restart()], max_retries=2)

    def kinds(*senders):
        return [getattr(fb.decide(HealthStatus.ALGORITHM_FAILURE, "llm", s), "kind", None) for s in senders]

    # Incarnation 1 fails at 30 Hz: switched once; after the switch (1, 1) it fails again: restarted once.
    assert kinds((1, 0), (1, 0), (1, 0), (1, 1), (1, 1), (1, 0)) == ["switch_model_client", None, None, "restart", None, None]
    assert kinds((2, 0), (2, 0)) == ["give_up", None]  # the third failing sender; max_retries=2
    fb = Fallback(on_algorithm_fail=restart(), max_retries=1)
    assert kinds((1, 0)) == ["restart"]
    assert fb.decide("HEALTHY", "llm", (1, 0)) is None and kinds((1, 0)) == [None]  # stale: ignored
    assert fb.decide("HEALTHY", "llm", (2, 0)) is None  # the replacement is well: the episode is over
    assert kinds((3, 0)) == ["restart"]


def test_fallback_counts_each_status_separately_and_no_rule_is_none():
    fb = Fallback(on_component_fail=restart(), on_system_fail=give_up(), max_retries=1)
    assert fb.decide("ALGORITHM_FAILURE") is None
    assert fb.decide("COMPONENT_FAILURE", "cam") == Action("restart", "cam")
    assert fb.decide("SYSTEM_FAILURE", "cam") == Action("give_up", "cam")
    assert fb.decide("COMPONENT_FAILURE", "cam") == Action("give_up", "cam")


def test_fallback_keeps_explicit_component_and_validates():
    fb = Fallback(on_algorithm_fail=restart("camera"))
    assert fb.decide("ALGORITHM_FAILURE", "llm").component == "camera"
    with pytest.raises(ValueError, match="max_retries"):
        Fallback(max_retries=-1)
    with pytest.raises(TypeError, match="on_system_fail"):
        Fallback(on_system_fail="restart")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="unknown health status"):
        fb.decide("sad")
