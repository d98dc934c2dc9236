"""Seeing what the robot does: topic tools, logs, MCAP record and replay, Foxglove live view.

The command-line modules (``topic_cli``, ``logs_cli``, ``record_cli``,
``play``, ``foxglove_view``) attach to a live run; :mod:`embagents.tools.root`
is what the run's root serves for them; :mod:`embagents.tools.recorder` is
the supervised recorder actor.

Example::

    >>> from embagents.tools import rotation_path
    >>> rotation_path("out.mcap", 1)
    'out.1.mcap'
"""

from embagents.tools.attach import Attached, find_topic, run_topics
from embagents.tools.dashboard import Dashboard, DashboardError
from embagents.tools.foxglove_view import FoxgloveView
from embagents.tools.mcap_codec import decode, kind_of
from embagents.tools.plain import build_message, format_text, to_plain
from embagents.tools.play import Stopped, read_messages
from embagents.tools.recorder import RecorderActor, rotation_files, rotation_path

__all__ = [
    "Attached",
    "Dashboard",
    "DashboardError",
    "FoxgloveView",
    "RecorderActor",
    "Stopped",
    "build_message",
    "decode",
    "find_topic",
    "format_text",
    "kind_of",
    "read_messages",
    "rotation_files",
    "rotation_path",
    "run_topics",
    "to_plain",
]
