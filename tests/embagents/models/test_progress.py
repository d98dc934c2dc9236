"""The progress bar: a terminal sees it move, a log file gets the last line only."""

from __future__ import annotations

import io

from embagents.models.progress import progress_bar


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_terminal_sees_every_step_in_place_and_the_line_ends_when_done() -> None:
    out = Terminal()
    show = progress_bar("converting", stream=out)
    for n in range(3):
        show(n, 2)
    assert out.getvalue() == ("\rconverting: [                              ] 0/2"
                              "\rconverting: [###############               ] 1/2"
                              "\rconverting: [##############################] 2/2\n")


def test_a_log_file_gets_only_the_last_line_and_a_disabled_bar_nothing() -> None:
    log = io.StringIO()
    show = progress_bar("converting", stream=log)
    for n in range(5):
        show(n, 4)
    assert log.getvalue() == "converting: [##############################] 4/4\n"
    quiet = io.StringIO()
    progress_bar("converting", False, stream=quiet)(4, 4)
    assert quiet.getvalue() == ""
