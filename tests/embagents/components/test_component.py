"""Component: declaration checks, triggers, the step contract, publishing, health."""

from __future__ import annotations

import logging

import pytest
from attrs import define, field

from actors.codec import Codec
from embagents.components import (
    Component,
    ComponentError,
    Health,
    HealthStatus,
    ModelComponent,
    lenient_construction,
)
from embagents.config import BaseComponentConfig, ConfigError
from embagents.events import Event, Fallback, on, restart, switch_model_client
from embagents.msgs import Audio, Image, String, Twist
from embagents.topic import Topic

TEXT = Topic("text", String)
IMAGE = Topic("camera/image", Image)
AUDIO = Topic("audio", Audio)
OUT = Topic("out", String)


class Describer(Component):
    """Needs an image, may take text or audio (one of), outputs String."""

    allowed_inputs = {"Required": [Image], "Optional": [[String, Audio]]}
    allowed_outputs = {"Required": [String]}

    def __init__(self, **kw):
        self.steps: list[dict] = []
        super().__init__(**kw)

    def _execution_step(self, **inputs):
        self.steps.append(inputs)
        self.publish("out", String(f"seen {sorted(self.fresh_inputs)}"))


def make(**kw) -> Describer:
    kw.setdefault("name", "describer")
    kw.setdefault("inputs", [IMAGE, TEXT])
    kw.setdefault("outputs", [OUT])
    return Describer(**kw)


# --- declaration ----------------------------------------------------------------------


def test_valid_component_has_no_problems():
    c = make(trigger=IMAGE)
    assert c.problems == [] and c.validate() == []
    assert c.trigger_kind == "topics" and c.required_inputs == (IMAGE,)


def test_missing_required_input_names_component_and_type():
    with pytest.raises(ComponentError) as err:
        make(inputs=[TEXT])
    msg = str(err.value)
    assert "'describer'" in msg and "Image" in msg and "required" in msg
    assert err.value.component == "describer"
    assert [code for code, _ in err.value.problems] == ["missing-input"]


def test_wrong_input_type_names_topic_and_allowed_types():
    with pytest.raises(ComponentError) as err:
        make(inputs=[IMAGE, Topic("cmd", Twist)])
    msg = str(err.value)
    assert "'describer'" in msg and "'cmd'" in msg and "Twist" in msg
    assert "allowed input types: Image, String, Audio" in msg


def test_output_type_not_allowed():
    with pytest.raises(ComponentError, match=r"output topic 'img_out' carries Image.*allowed output types: String"):
        make(outputs=[OUT, Topic("img_out", Image)])


def test_missing_required_output():
    with pytest.raises(ComponentError, match="needs an output topic of type String"):
        make(outputs=[])


def test_one_of_list_accepts_either_type():
    assert make(inputs=[IMAGE, AUDIO]).problems == []


def test_all_problems_reported_together():
    with pytest.raises(ComponentError) as err:
        make(inputs=[Topic("cmd", Twist)], outputs=[], trigger=Topic("elsewhere", String))
    codes = sorted(code for code, _ in err.value.problems)
    assert codes == ["missing-input", "missing-output", "trigger-not-input", "wrong-input-type"]


def test_trigger_not_in_inputs_names_component_and_topic():
    with pytest.raises(ComponentError) as err:
        make(trigger=Topic("other", String))
    assert "component 'describer'" in str(err.value) and "'other'" in str(err.value)


def test_trigger_topic_with_same_name_but_other_type_is_not_an_input():
    with pytest.raises(ComponentError, match="trigger topic 'text'"):
        make(trigger=Topic("text", Audio))


@pytest.mark.parametrize("trigger", [0, -1.0, "10", [], [TEXT, "x"], True])
def test_bad_triggers(trigger):
    with pytest.raises(ComponentError, match="rate|trigger"):
        make(trigger=trigger)


def test_rate_trigger_is_in_hz_and_sets_loop_rate():
    c = make(trigger=10)
    assert c.trigger_kind == "rate" and c.rate_hz == 10.0 and c.config.loop_rate_hz == 10.0
    assert make(trigger=IMAGE).rate_hz is None


def test_topic_list_trigger_any_fires():
    c = make(trigger=[IMAGE, TEXT])
    assert c.on_message("text", String("a")) is True
    assert c.on_message("camera/image", Image()) is True
    assert c.on_message("unrelated", String("a")) is False


def test_event_trigger_subscribes_to_event_topics():
    alarm = Topic("alarm", String)
    ev = Event("alarm_on", on(alarm).field("data") == "on")
    c = make(trigger=ev)
    assert [t.name for t in c.subscriptions] == ["camera/image", "text", "alarm"]
    assert c.on_message("alarm", String("off")) is False
    assert c.on_message("alarm", String("on")) is True
    assert c.on_message("alarm", String("on")) is False  # rising edge only


def test_no_trigger_is_a_server_that_never_fires():
    c = make()
    assert c.trigger_kind == "none" and c.on_message("camera/image", Image()) is False


def test_lenient_mode_collects_instead_of_raising():
    with lenient_construction():
        c = make(inputs=[TEXT], trigger=Topic("zz", String))
    assert {code for code, _ in c.problems} == {"missing-input", "trigger-not-input"}
    with pytest.raises(ComponentError):  # and only inside the block
        make(inputs=[TEXT])


def test_bad_name_and_non_topic_inputs():
    with pytest.raises(ComponentError) as err:
        make(name="9 lives", inputs=[IMAGE, "text"])
    codes = {code for code, _ in err.value.problems}
    assert codes == {"bad-name", "bad-topic"}


def test_duplicate_input_topic():
    with pytest.raises(ComponentError, match="input topic 'camera/image' is listed twice"):
        make(inputs=[IMAGE, IMAGE])


def test_bad_allowed_spec_fails_at_class_definition():
    with pytest.raises(TypeError, match="allowed_inputs"):

        class Broken(Component):
            allowed_inputs = {"Needed": [String]}


# --- config ---------------------------------------------------------------------------


@define(kw_only=True)
class ListConfig(BaseComponentConfig):
    words: list[str] = field(factory=list)


class Lister(Component):
    config_class = ListConfig


def test_config_is_deep_copied_per_component():
    shared = ListConfig(words=["a"])
    a, b = Lister(name="a", config=shared), Lister(name="b", config=shared)
    a.config.words.append("x")
    assert b.config.words == ["a"] and shared.words == ["a"]


def test_log_level_is_the_level_of_the_components_logger(caplog: pytest.LogCaptureFixture) -> None:
    quiet = Lister(name="quiet_one", log_level="warning")
    assert quiet.logger.name == "embagents.component.quiet_one" and quiet.logger.level == logging.WARNING
    with caplog.at_level(logging.DEBUG):
        quiet.logger.info("not shown")
        quiet.reconfigure({"log_level": "debug"})
        quiet.logger.info("shown")
    assert [r.getMessage() for r in caplog.records] == ["shown"]
    with pytest.raises(ConfigError):
        quiet.reconfigure({"log_level": "loud"})
    assert quiet.logger.level == logging.DEBUG  # a refused reconfigure changes nothing


def test_config_overrides_as_keywords_and_wrong_config_class():
    assert Lister(name="a", log_level="debug").config.log_level == "debug"
    with pytest.raises(ComponentError, match="unknown argument 'wordz'; Lister takes name, inputs.*; or a key of ListConfig: "):
        Lister(name="a", wordz=[])
    with pytest.raises(ComponentError, match="config must be a ListConfig, got BaseComponentConfig"):
        Lister(name="a", config=BaseComponentConfig())


def test_reconfigure_validates_and_calls_hook():
    seen = []

    class Hooked(Component):
        def on_reconfigure(self, old_config):
            seen.append((old_config.loop_rate_hz, self.config.loop_rate_hz))

    c = Hooked(name="h", trigger=5.0)
    c.reconfigure({"loop_rate_hz": 2})
    assert c.rate_hz == 2.0 and seen == [(5.0, 2.0)]
    with pytest.raises(ConfigError, match="loop_rate_hz"):
        c.reconfigure({"loop_rate_hz": -1})
    assert c.rate_hz == 2.0


# --- steps ----------------------------------------------------------------------------


def attached(c: Component) -> list[tuple[str, object]]:
    sent: list[tuple[str, object]] = []
    c.attach(lambda topic, msg: sent.append((topic, msg)))
    return sent


def test_step_waits_for_required_inputs_and_gets_latest_of_each():
    c = make(trigger=[IMAGE, TEXT])
    sent = attached(c)
    assert c.on_message("text", String("hello"))
    assert c.missing_inputs() == ["camera/image"]
    assert c.execute() is False and c.steps == []
    img = Image()
    assert c.on_message("camera/image", img) and c.execute() is True
    assert c.steps == [{"camera/image": img, "text": String("hello")}]
    assert sent == [("out", String("seen ['camera/image', 'text']"))]
    c.on_message("camera/image", img)
    c.execute()
    assert sent[-1] == ("out", String("seen ['camera/image']"))  # text is not fresh any more


def test_optional_input_not_heard_from_is_none():
    c = make(trigger=IMAGE)
    attached(c)
    c.on_message("camera/image", Image())
    c.execute()
    assert c.steps[0]["text"] is None


def test_stale_input_counts_as_missing():
    c = make(trigger=IMAGE, input_max_age_s=0.5)
    attached(c)
    c.on_message("camera/image", Image(), now=100.0)
    assert c.execute(now=100.4) is True
    assert c.execute(now=101.0) is False
    assert c.missing_inputs(now=101.0) == ["camera/image"]


def test_a_waiting_step_says_once_which_input_it_waits_for_and_can_run_with_what_is_there(caplog):
    c = make(trigger=5.0)  # a rate: each tick calls execute()
    attached(c)
    with caplog.at_level(logging.INFO, "embagents.component.describer"):
        assert c.execute() is False and c.execute() is False and c.steps == []
    waits = [r.getMessage() for r in caplog.records if "waits for" in r.getMessage()]
    assert len(waits) == 1 and "required input 'camera/image'" in waits[0] and "wait_for_inputs=False" in waits[0]
    eager = make(trigger=5.0, wait_for_inputs=False)
    attached(eager)
    assert eager.execute() is True and eager.steps == [{"camera/image": None, "text": None}]


def test_a_queued_input_gives_the_step_every_message_since_the_last_one_up_to_its_bound(caplog):
    c = make(trigger=5.0, queued={TEXT: 3})
    attached(c)
    c.on_message("camera/image", Image())
    for word in ("a", "b"):
        c.on_message("text", String(word))
    assert c.execute() and [m.data for m in c.steps[-1]["text"]] == ["a", "b"]
    assert c.execute() and c.steps[-1]["text"] == []  # heard before, nothing new since
    with caplog.at_level(logging.WARNING, "embagents.component.describer"):
        for word in "cdefg":
            c.on_message("text", String(word))
    assert c.execute() and [m.data for m in c.steps[-1]["text"]] == ["e", "f", "g"]
    assert c.dropped == {"text": 2} and len([r for r in caplog.records if "is full" in r.getMessage()]) == 1
    assert make(trigger=5.0, queued=[TEXT]).queued == {"text": TEXT.queue_size}
    with pytest.raises(ComponentError, match="queued topic 'audio' is not one of its inputs"):
        make(queued={AUDIO: 5})
    with pytest.raises(ComponentError, match=r"queued\['text'\]: the bound .* got 0"):
        make(queued={TEXT: 0})


def test_publish_checks_type_and_output_name():
    c = make()
    attached(c)
    with pytest.raises(TypeError) as err:
        c.publish("out", Image())
    assert "'out'" in str(err.value) and "String" in str(err.value) and "Image" in str(err.value)
    with pytest.raises(ValueError, match="no output topic 'nope'; outputs: out"):
        c.publish("nope", String())
    c.publish(OUT, String("ok"))


def test_publish_without_runtime_is_a_clear_error():
    with pytest.raises(RuntimeError, match="not attached"):
        make().publish("out", String())


def test_base_step_not_implemented_is_an_algorithm_failure():
    c = Component(name="plain", trigger=1.0)
    assert c.execute() is False
    assert c.health_status is HealthStatus.ALGORITHM_FAILURE
    assert "NotImplementedError" in c.health.text


# --- health ---------------------------------------------------------------------------


class Flaky(Component):
    def __init__(self, **kw):
        self.fail = True
        super().__init__(**kw)

    def _execution_step(self, **inputs):
        if self.fail:
            raise ValueError("bad frame")


def test_step_exception_reports_every_failure_and_recovery_once():
    c = Flaky(name="flaky", trigger=1.0)
    reports: list[Health] = []
    c.attach(lambda t, m: None, on_health=reports.append)
    assert c.execute() is False and c.execute() is False
    assert [r.status for r in reports] == [HealthStatus.ALGORITHM_FAILURE] * 2
    assert reports[0].component == "flaky" and "ValueError: bad frame" in reports[0].text
    c.fail = False
    assert c.execute() and c.execute()
    assert [r.status for r in reports][2:] == [HealthStatus.HEALTHY]


def test_step_that_sets_its_own_status_keeps_it():
    class Picky(Component):
        def _execution_step(self, **inputs):
            self.set_system_failure("camera unplugged")

    c = Picky(name="p", trigger=1.0)
    assert c.execute() is True
    assert c.health_status is HealthStatus.SYSTEM_FAILURE and c.health.text == "camera unplugged"


def test_health_status_setter_and_codec_roundtrip():
    c = make()
    c.health_status = "component_failure"
    assert c.health_status is HealthStatus.COMPONENT_FAILURE
    codec = Codec()
    back = codec.decode(codec.encode(c.health)[0])
    assert back == c.health and back.status is HealthStatus.COMPONENT_FAILURE
    with pytest.raises(ValueError, match="known: HEALTHY"):
        HealthStatus.parse("fine")


def test_health_topic_can_name_the_type():
    assert Topic("health", "Health").msg_type is Health


def test_lifecycle_hooks_are_noops_and_snapshot_is_none():
    c = make()
    for hook in (c.on_configure, c.on_activate, c.on_deactivate, c.on_cleanup, c.on_shutdown):
        hook()
    assert c.snapshot() is None
    c.restore(None)


# --- ModelComponent -------------------------------------------------------------------


class Client:
    def __init__(self, name: str, reply: str = "hi"):
        self.name = name
        self.reply = reply
        self.calls: list[tuple[list, dict]] = []

    def chat_stream(self, messages, **options):
        self.calls.append((messages, options))
        yield {"delta": self.reply}
        yield {"done": True, "finish_reason": "stop", "tool_calls": None}


def test_change_model_client_by_name_object_and_unknown():
    main, backup = Client("main"), Client("backup")
    mc = ModelComponent(name="m", model_client=main, extra_clients=[backup])
    assert mc.client_name == "main" and list(mc.clients) == ["main", "backup"]
    assert mc.change_model_client("backup") == "main" and mc.model_client is backup
    with pytest.raises(ValueError, match="no model client 'cloud'; known clients: main, backup"):
        mc.change_model_client("cloud")
    third = Client("third")
    mc.change_model_client(third)
    assert mc.model_client is third and "third" in mc.clients
    with pytest.raises(ValueError, match="different model client named 'main'"):
        mc.change_model_client(Client("main"))


def test_extra_clients_as_dict_use_the_keys():
    mc = ModelComponent(name="m", model_client=Client("a"), extra_clients={"local": Client("a")})
    assert list(mc.clients) == ["a", "local"]


def test_model_component_client_problems():
    with pytest.raises(ComponentError, match="component 'm'.*needs a model_client"):
        ModelComponent(name="m")
    with pytest.raises(ComponentError, match="neither chat_stream"):
        ModelComponent(name="m", model_client=object())
    with pytest.raises(ComponentError, match="two different model clients are named 'a'"):
        ModelComponent(name="m", model_client=Client("a"), extra_clients=[Client("a")])


def test_fallback_switching_to_unknown_client_is_a_problem():
    fb = Fallback(on_algorithm_fail=switch_model_client("cloud"))
    with pytest.raises(ComponentError, match="'cloud'.*known clients: main"):
        ModelComponent(name="m", model_client=Client("main"), fallback=fb)
    with pytest.raises(ComponentError, match="needs a ModelComponent"):
        Component(name="c", fallback=fb)
    assert Component(name="c", fallback=Fallback(on_algorithm_fail=restart())).problems == []


def test_warmup_sends_one_tiny_request_of_the_modality_on_configure():
    class Warmed(ModelComponent):
        def run_warmup(self) -> None:
            for _ in self.model_client.chat_stream([{"role": "user", "content": "Hi"}], max_tokens=1):
                pass

    client = Client("main")
    Warmed(name="m", model_client=client).on_configure()
    assert client.calls == []
    Warmed(name="m", model_client=client, warmup=True).on_configure()
    assert len(client.calls) == 1 and client.calls[0][1] == {"max_tokens": 1}


def test_a_model_component_without_its_own_warmup_names_the_fix():
    with pytest.raises(NotImplementedError, match="no run_warmup"):
        ModelComponent(name="m", model_client=Client("main"), warmup=True).on_configure()


def test_the_client_method_a_component_needs_is_a_class_attribute_checked_once():
    class Detecting(ModelComponent):
        client_methods = ("detect",)
        client_task = "detect"
        client_fix = "LocalModelClient(DetectorModel(...))"

    class Detector:
        name = "det"

        def detect(self, image):
            return []

    assert list(Detecting(name="v", model_client=Detector()).clients) == ["det"]
    with pytest.raises(ComponentError, match=r"model client 'main' cannot detect \(it has no detect\(\)\); "
                                             r"give it LocalModelClient\(DetectorModel"):
        Detecting(name="v", model_client=Client("main"))
    with pytest.raises(TypeError, match="cannot detect"):
        Detecting(name="v", model_client=Detector()).change_model_client(Client("chatty"))


def test_health_reports_name_their_sender_and_a_fresh_incarnation_reports_its_first_status():
    mc = ModelComponent(name="m", model_client=Client("main"), extra_clients=[Client("backup")], trigger=1.0)
    reports: list[Health] = []
    mc.attach(lambda t, m: None, on_health=reports.append, incarnation=4)
    mc.set_healthy()  # unchanged, but the first status of this incarnation: a replacement says it is well
    mc.set_healthy()
    mc.set_algorithm_failure("bad answer")
    mc.change_model_client("backup")
    mc.set_algorithm_failure("bad answer")
    assert [(r.status, r.incarnation, r.switches) for r in reports] == [
        (HealthStatus.HEALTHY, 4, 0), (HealthStatus.ALGORITHM_FAILURE, 4, 0), (HealthStatus.ALGORITHM_FAILURE, 4, 1)]
