"""Seeing what the robot does: the machinery behind the operator commands.

The commands (:mod:`embagents.cli`: ``topic``, ``logs``, ``record``, ``play``,
``view``, ``call``, ``publish``) attach to a live run; :mod:`embagents.tools.root`
is what the run's root serves for them, with the handlers of ``call``
(:mod:`embagents.tools.call`) and ``publish`` (:mod:`embagents.tools.publish`);
:mod:`embagents.tools.recorder` is the supervised recorder actor,
:mod:`embagents.tools.dashboard` the web dashboard, :mod:`embagents.tools.graph`
draws a system.

Example::

    >>> from embagents.tools import rotation_path
    >>> rotation_path("out.mcap", 1)
    'out.1.mcap'
"""

from embagents.tools.attach import Attached, find_topic, run_topics
from embagents.tools.dashboard import Dashboard, DashboardError
from embagents.tools.mcap_codec import decode, kind_of
from embagents.tools.plain import build_message, format_text, to_plain
from embagents.tools.recorder import RecorderActor, rotation_files, rotation_path

__all__ = [
    "Attached",
    "Dashboard",
    "DashboardError",
    "RecorderActor",
    "build_message",
    "decode",
    "find_topic",
    "format_text",
    "kind_of",
    "rotation_files",
    "rotation_path",
    "run_topics",
    "to_plain",
]
