"""System declarations and loading system.py files."""

from __future__ import annotations

import sys
import textwrap

import pytest

from embagents.components import Component
from embagents.events import Event, on, restart, start
from embagents.msgs import String
from embagents.system import SUPERVISION_DEFAULTS, System, SystemFileError, load_system
from embagents.topic import Topic

TEXT = Topic("text", String)

HEADER = """\
from embagents.components import Component
from embagents.msgs import String
from embagents.system import System
from embagents.topic import Topic

text = Topic("text", String)
"""


def write(tmp_path, body: str, name: str = "system.py"):
    path = tmp_path / name
    path.write_text(HEADER + textwrap.dedent(body))
    return path


# --- System ---------------------------------------------------------------------------


def test_events_as_dict_or_pairs_become_action_tuples():
    a = Component(name="a", inputs=[TEXT])
    ev = Event("e", on(TEXT).field("data") == "go")
    assert System([a], events={ev: start(a)}).events == [(ev, (start("a"),))]
    assert System([a], events=[(ev, [start(a), restart(a)])]).events == [(ev, (start("a"), restart("a")))]
    with pytest.raises(TypeError, match="expected an Event as key"):
        System([a], events={"e": start(a)})
    with pytest.raises(TypeError, match="event 'e': expected an Action"):
        System([a], events={ev: "start"})


def test_components_must_be_components():
    with pytest.raises(TypeError, match=r"components\[1\] is not a Component"):
        System([Component(name="a"), "b"])
    with pytest.raises(TypeError, match="must be a list"):
        System(Component(name="a"))


def test_supervision_defaults_and_validation():
    assert System([]).supervision == SUPERVISION_DEFAULTS
    sup = System([], supervision={"strategy": "rest_for_one", "period": 10}).supervision
    assert sup == {"strategy": "rest_for_one", "intensity": 3, "period": 10.0}
    with pytest.raises(ValueError, match="unknown supervision key\\(s\\) 'retries'; valid: strategy"):
        System([], supervision={"retries": 3})
    with pytest.raises(TypeError, match="supervision must be a dict"):
        System([], supervision=["one_for_all"])
    # The values are the supervision tree's to judge (`embagents check` builds it; see test_check).
    assert System([], supervision={"intensity": -1}).supervision["intensity"] == -1


def test_topics_and_component_lookup():
    out = Topic("out", String)
    system = System([Component(name="a", inputs=[TEXT], outputs=[out])], ros=["opaque"], models=["m"])
    assert sorted(system.topics) == ["out", "text"] and system.ros == ["opaque"] and system.models == ["m"]
    assert system.component("a").name == "a"
    with pytest.raises(KeyError, match="no component named 'b'.*components: a"):
        system.component("b")


# --- load_system ----------------------------------------------------------------------


def test_load_finds_the_system_and_local_imports_work(tmp_path):
    (tmp_path / "mytopics.py").write_text("from embagents.msgs import String\nfrom embagents.topic import Topic\n"
                                          "answer = Topic('answer', String)\n")
    path = write(tmp_path, """
        from mytopics import answer
        system = System([Component(name="a", inputs=[text], outputs=[answer])], name="demo")
        alias = system
        if __name__ == "__main__":
            raise SystemExit("must not run")
    """)
    system = load_system(path)
    assert system.name == "demo" and [t.name for t in system.components[0].outputs] == ["answer"]
    assert str(tmp_path) in sys.path


def test_each_load_is_a_fresh_module(tmp_path):
    path = write(tmp_path, "system = System([Component(name='a')])\n")
    assert load_system(path) is not load_system(path)


def test_no_system_says_how_to_define_one(tmp_path):
    path = write(tmp_path, "x = 1\n")
    with pytest.raises(SystemFileError, match="define `system = System\\(...\\)` at top level"):
        load_system(path)


def test_several_systems_are_named(tmp_path):
    path = write(tmp_path, "one = System([])\ntwo = System([])\n")
    with pytest.raises(SystemFileError, match="found 2 Systems \\(one, two\\)"):
        load_system(path)


def test_exception_names_file_line_and_cause(tmp_path):
    path = write(tmp_path, """
        x = 1
        bad = Topic("text", "Strng")
    """)
    with pytest.raises(SystemFileError) as err:
        load_system(path)
    msg = str(err.value)
    assert f"{path}:9:" in msg and "TopicError" in msg and "'Strng'" in msg and 'bad = Topic("text", "Strng")' in msg
    assert err.value.line == 9 and err.value.cause is not None


def test_syntax_error_names_the_line(tmp_path):
    path = write(tmp_path, "system = System([)\n")
    with pytest.raises(SystemFileError, match=f"{path}:7: SyntaxError"):
        load_system(path)


def test_component_error_is_wrapped_naming_the_component(tmp_path):
    path = write(tmp_path, """
        from embagents.components import LLM
        llm = LLM(name="talker", inputs=[], outputs=[text], model_client=None)
        system = System([llm])
    """)
    with pytest.raises(SystemFileError) as err:
        load_system(path)
    msg = str(err.value)
    assert "invalid component" in msg and "component 'talker'" in msg and ":9:" in msg


def test_lenient_load_keeps_problems_on_components(tmp_path):
    path = write(tmp_path, """
        from embagents.components import LLM
        llm = LLM(name="talker", inputs=[], outputs=[text], model_client=None)
        system = System([llm])
    """)
    system = load_system(path, lenient=True)
    assert {code for code, _ in system.components[0].problems} == {"missing-input", "missing-client"}


def test_system_exit_in_the_file_is_reported(tmp_path):
    path = write(tmp_path, "raise SystemExit(3)\n")
    with pytest.raises(SystemFileError, match="SystemExit"):
        load_system(path)


def test_missing_file(tmp_path):
    with pytest.raises(SystemFileError, match="no such file"):
        load_system(tmp_path / "nope.py")


def test_a_directory_is_named_as_one_with_a_system_file_to_pass(tmp_path):
    write(tmp_path, "system = System([Component(name='a')])\n", name="robot.py")
    (tmp_path / "helpers.py").write_text("x = 1\n")
    with pytest.raises(SystemFileError) as err:
        load_system(tmp_path)
    assert str(err.value) == (f"{tmp_path}: is a directory, not a system file; "
                              f"pass one of its system files, e.g. `{tmp_path / 'robot.py'}`")


def test_a_misspelt_name_keeps_pythons_did_you_mean_and_shows_the_line_as_source(tmp_path):
    path = write(tmp_path, """
        from embagents.components import LLM
        llm = LMM(name="talker",
                  inputs=[text])
    """)
    with pytest.raises(SystemFileError) as err:
        load_system(path)
    first, source = str(err.value).split("\n")
    assert first == f"{path}:9: NameError: name 'LMM' is not defined. Did you mean: 'LLM'?"
    assert source == '    llm = LMM(name="talker",'


def test_managers_are_checked_and_found_by_name() -> None:
    from embagents.manager import Manager

    boss = Manager(10, name="boss")
    system = System([], managers=[boss])
    assert system.manager("boss") is boss
    with pytest.raises(KeyError, match="no manager named 'x' in system 'system'; managers: boss"):
        system.manager("x")
    with pytest.raises(TypeError, match="System managers must be Manager objects, got 'boss'"):
        System([], managers=["boss"])
