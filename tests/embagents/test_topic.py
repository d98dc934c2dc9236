"""Topic: name and type validation, queue policy."""

from __future__ import annotations

import attrs
import pytest

from embagents.msgs import Image, String
from embagents.topic import Topic, TopicError, known_message_types, resolve_msg_type


def test_type_by_class_class_name_or_wire_name():
    assert Topic("a", Image).msg_type is Image
    assert Topic("a", "Image").msg_type is Image
    assert Topic("a", "embagents/Image").msg_type is Image
    assert Topic("a", "String").type_name == "String"


def test_leading_slash_is_dropped_so_both_spellings_are_one_topic():
    assert Topic("/camera/image", Image) == Topic("camera/image", Image)
    assert Topic("/camera/image", Image).name == "camera/image"


@pytest.mark.parametrize("name", ["", "9lives", "a//b", "a/", "a b", "cam-1", "a/9b", "//a", 5, None])
def test_invalid_names_are_refused_with_the_rule(name):
    with pytest.raises(TopicError, match="invalid topic name.*letters, digits and '_'"):
        Topic(name, String)


@pytest.mark.parametrize("name", ["a", "_x", "camera/image_raw", "/robot1/cmd_vel", "A/B/C9"])
def test_valid_names(name):
    assert Topic(name, String).name == name.lstrip("/")


def test_unknown_type_name_lists_known_types():
    with pytest.raises(TopicError) as err:
        Topic("a", "Imagee")
    msg = str(err.value)
    assert "'a'" in msg and "'Imagee'" in msg
    for known in ("Image", "String", "Twist", "JointState"):
        assert known in msg


def test_unregistered_class_is_refused():
    @attrs.define
    class NotAMessage:
        x: int = 0

    with pytest.raises(TopicError, match="NotAMessage is not a registered message class.*known types"):
        Topic("a", NotAMessage)
    with pytest.raises(TopicError, match="must be a message class or its name"):
        Topic("a", 3)


def test_queue_policy_defaults_and_validation():
    t = Topic("a", String)
    assert (t.queue_size, t.keep) == (10, "latest")
    assert Topic("a", String, queue_size=1, keep="all").keep == "all"
    with pytest.raises(TopicError, match="queue_size must be an int >= 1"):
        Topic("a", String, queue_size=0)
    with pytest.raises(TopicError, match="keep must be 'latest' or 'all'"):
        Topic("a", String, keep="newest")


def test_topics_are_frozen_and_hashable():
    t = Topic("a", String)
    with pytest.raises(attrs.exceptions.FrozenInstanceError):
        t.name = "b"  # type: ignore[misc]
    assert len({t, Topic("a", "String")}) == 1
    assert str(t) == "a (String)"


def test_known_types_and_resolve():
    assert known_message_types()["Image"] is Image
    assert resolve_msg_type(String) is String
