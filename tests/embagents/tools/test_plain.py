"""Messages as plain data (topic echo) and from plain data (topic pub), naming the field that does not fit."""

from __future__ import annotations

import numpy as np
import pytest

from embagents.msgs import Detections, Image, JointState, RosMessage, String, Twist
from embagents.tools.plain import build_message, format_text, to_plain


def test_arrays_are_summarised_unless_asked() -> None:
    img = Image(data=np.zeros((4, 5, 3), np.uint8))
    assert to_plain(img)["data"] == "<array shape=(4, 5, 3) dtype=uint8>"
    assert to_plain(img, full_arrays=True)["data"][0][0] == [0, 0, 0]
    assert "encoding: rgb8" in format_text(to_plain(img))


def test_an_introspected_ros_message_echoes_its_ros_fields() -> None:
    fix = RosMessage("sensor_msgs/msg/NavSatFix", {"header": RosMessage("std_msgs/msg/Header", {"stamp": 1.5}),
                                                   "latitude": 48.1, "position_covariance": np.zeros(9)})
    assert to_plain(fix) == {"header": {"stamp": 1.5}, "latitude": 48.1,
                             "position_covariance": "<array shape=(9,) dtype=float64>"}
    assert "header:\n  stamp: 1.5\nlatitude: 48.1" in format_text(to_plain(fix))


def test_build_message_converts_plain_fields() -> None:
    assert build_message(Twist, {"linear": [1, 0, 0]}).linear == (1.0, 0.0, 0.0)
    js = build_message(JointState, {"name": ["a", "b"], "position": [0.1, 0.2]})
    assert js.position.dtype == np.float64 and js.name == ["a", "b"]


@pytest.mark.parametrize(("cls", "fields", "says"), [
    (String, {"data": 5}, "String field 'data' must be a str, got 5 (int)"),
    (String, {"text": "x"}, "String has no field 'text'; fields of String: data (str)"),
    (Twist, {"linear": [1, 2]}, "Twist field 'linear' must be a tuple[float, float, float]"),
    (JointState, {"name": "a"}, "JointState field 'name' must be a list[str]"),
    (Detections, {"boxes": [[0, 0, 1, 1]]}, "as many labels, scores as boxes"),
    (String, "hi", "String data must be a mapping of fields"),
])
def test_data_that_does_not_fit_names_the_field(cls: type, fields: object, says: str) -> None:
    with pytest.raises(ValueError) as err:
        build_message(cls, fields)  # type: ignore[arg-type]
    assert says in str(err.value)
