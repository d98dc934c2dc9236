"""The ``embagents`` command line: the lazy dispatch table of its commands.

Each subcommand is a :class:`Command` in :data:`COMMANDS`: a function adding
its arguments to an argparse subparser and a function running it (returning
the exit code), each in one module of this package (``embagents.cli.topic``
for ``embagents topic``). A command's module is imported only when that
command runs or its arguments are asked for, so ``embagents check`` stays
light. Adding one is a dict entry:

    >>> def _hello_arguments(parser):
    ...     parser.add_argument("name")
    >>> def _hello(args):
    ...     print(f"hello {args.name}")
    ...     return 0
    >>> COMMANDS["hello"] = Command(_hello_arguments, _hello, "say hello")
    >>> main(["hello", "robot"])
    hello robot
    0
    >>> del COMMANDS["hello"]

Example::

    >>> main(["check", "/no/such/system.py"])
    error: [load-error] /no/such/system.py: no such file
    1
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

__all__ = ["COMMANDS", "Command", "build_parser", "main"]


class Command(NamedTuple):
    """A subcommand: ``add_arguments(parser)``, ``run(args) -> exit code``, one-line help."""

    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]
    help: str = ""


def _lazy(module: str, what: str) -> Callable[..., Any]:
    """A function that imports ``module`` only when called (keeps `embagents check` light)."""

    def call(*args: Any) -> Any:
        return getattr(importlib.import_module(module), what)(*args)

    return call


def _command(module: str, helptext: str, arguments: str = "arguments", run: str = "run") -> Command:
    return Command(_lazy(f"embagents.cli.{module}", arguments), _lazy(f"embagents.cli.{module}", run), helptext)


#: Subcommand name -> Command. Other modules may add entries before main() runs.
COMMANDS: dict[str, Command] = {
    "check": _command("check", "validate a system's wiring without starting anything"),
    "graph": _command("graph", "draw a system as SVG or PNG"),
    "status": _command("control", "a table of the running system: name, pid, state, restarts, uptime, CPU, memory, mailbox",
                       "status_arguments"),
    "restart": _command("control", "restart one actor of the running system", "restart_arguments"),
    "stop": _command("control", "stop the running system cleanly (reverse start order)", "run_arguments"),
    "publish": _command("topic", "publish a message on a topic of the running system (`topic pub` without the type)",
                        "publish_arguments", "publish_run"),
    "call": _command("call", "run a component's action in the running system "
                     "(e.g. embagents call vlm describe camera 'what do you see?')"),
    "supervise": _command("supervise", "run a system.py under supervision"),
    "keys": _command("keys", "make a CURVE key pair for model actors on another machine; prints the public key"),
    "serve-model": _command("serve_model", "serve a model actor to other machines over TCP with CURVE "
                            "(only allowed keys get in)"),
    "serve-policy": _command("serve_policy", "serve a policy over openpi's WebSocket protocol "
                             "(openpi clients drive our policies)"),
    "topic": _command("topic", "list, echo, measure (hz) and publish the topics of the running system"),
    "logs": _command("logs", "show (and follow with -f) one actor's log lines"),
    "record": _command("record", "record the running system's topics to an MCAP file (a supervised recorder)"),
    "play": _command("play", "publish an MCAP recording into the running system (recorded timing, faster, stepped)"),
    "view": _command("view", "serve the running system's topics to Foxglove (WebSocket, no ROS)"),
    "bench": Command(_lazy("embagents.cli.bench", "arguments"), _lazy("embagents.bench", "run"),
                     "measure embagents side by side with raw pyzmq, multiprocessing queues and rclpy"),
}


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("embagents")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "(not installed)"


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The argument parser with one subparser per entry of :data:`COMMANDS`.

    ``only``: add the arguments of that command alone (the others' modules stay unimported).
    """
    parser = argparse.ArgumentParser(prog="embagents", description="Run and inspect embagents systems.")
    parser.add_argument("--version", action="version", version=f"embagents {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, command in COMMANDS.items():
        p = sub.add_parser(name, help=command.help, description=command.help)
        if only is None or name == only:
            command.add_arguments(p)
    return parser


#: Options whose value is a CURVE public key: 40 Z85 characters, which may begin with "-".
_KEY_OPTIONS = ("--allow",)


def _keys_attached(argv: Sequence[str]) -> list[str]:
    """``--allow KEY`` as ``--allow=KEY`` when KEY starts with "-" (argparse would take it for an option).

    >>> _keys_attached(["serve-model", "m.gguf", "--allow", "-[UnAGwJQBF2O7&2zL+<@g[$NF)xF4q-6RKN)DTA"])
    ['serve-model', 'm.gguf', '--allow=-[UnAGwJQBF2O7&2zL+<@g[$NF)xF4q-6RKN)DTA']
    >>> _keys_attached(["serve-model", "--allow", "-v"])  # not a key: left for argparse to explain
    ['serve-model', '--allow', '-v']
    """
    out: list[str] = []
    i = 0
    while i < len(argv):
        a = argv[i]
        nxt = argv[i + 1] if i + 1 < len(argv) else ""
        if a in _KEY_OPTIONS and nxt.startswith("-") and len(nxt) == 40:
            out.append(f"{a}={nxt}")
            i += 2
            continue
        out.append(a)
        i += 1
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (2 for usage errors)."""
    argv = _keys_attached(sys.argv[1:] if argv is None else argv)
    chosen = next((a for a in argv if not a.startswith("-")), None)
    parser = build_parser(chosen if chosen in COMMANDS else None)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse exits on --help and usage errors
        return int(exc.code or 0)
    return COMMANDS[args.command].run(args)
