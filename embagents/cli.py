"""The ``embagents`` command line.

Each subcommand is a :class:`Command` in :data:`COMMANDS`: a function adding
its arguments to an argparse subparser and a function running it (returning
the exit code). Adding one is a dict entry:

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
import contextlib
import importlib
import os
import sys
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

__all__ = ["COMMANDS", "Command", "build_parser", "main"]


class Command(NamedTuple):
    """A subcommand: ``add_arguments(parser)``, ``run(args) -> exit code``, one-line help."""

    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]
    help: str = ""


def _system_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("system", metavar="SYSTEM_PY", help="the system.py file declaring `system = System(...)`")


def _check_arguments(parser: argparse.ArgumentParser) -> None:
    _system_argument(parser)
    parser.add_argument("--offline", action="store_true",
                        help="embagents.compat recipes: replace model servers by the offline default models")


def _check(args: argparse.Namespace) -> int:
    from embagents.check import check_file, errors
    from embagents.system import counted

    if getattr(args, "offline", False):
        os.environ["EMBAGENTS_OFFLINE"] = "1"  # read by embagents.compat's clients
    system, problems = check_file(args.system)
    for p in problems:
        print(p)
    bad = errors(problems)
    if bad:
        warned = len(problems) - len(bad)
        print(counted(len(bad), "error") + (f", {counted(warned, 'warning')}" if warned else ""), file=sys.stderr)
        return 1
    assert system is not None  # no errors means it loaded
    summary = f"OK: {counted(len(system.components), 'component')}, {counted(len(system.topics), 'topic')}"
    if system.managers:
        summary += f", {counted(len(system.managers), 'manager')}"
    print(summary + (f" ({counted(len(problems), 'warning')})" if problems else ""))
    return 0


def _graph_arguments(parser: argparse.ArgumentParser) -> None:
    _system_argument(parser)
    parser.add_argument("-o", "--output", required=True, metavar="FILE", help="where to draw: .svg or .png")


def _graph(args: argparse.Namespace) -> int:
    from embagents.graph import render_graph
    from embagents.system import SystemFileError, load_system

    try:
        system = load_system(args.system, lenient=True)  # draw broken systems too: it helps fix them
        render_graph(system, args.output)
    except (SystemFileError, ValueError, OSError, RuntimeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {args.output}")
    return 0


#: Subcommand name -> Command. Other modules may add entries before main() runs.
COMMANDS: dict[str, Command] = {
    "check": Command(_check_arguments, _check, "validate a system's wiring without starting anything"),
    "graph": Command(_graph_arguments, _graph, "draw a system as SVG or PNG"),
}


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("embagents")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "(not installed)"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with one subparser per entry of :data:`COMMANDS`."""
    parser = argparse.ArgumentParser(prog="embagents", description="Run and inspect embagents systems.")
    parser.add_argument("--version", action="version", version=f"embagents {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, command in COMMANDS.items():
        command.add_arguments(sub.add_parser(name, help=command.help, description=command.help))
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
    parser = build_parser()
    try:
        args = parser.parse_args(_keys_attached(sys.argv[1:] if argv is None else argv))
    except SystemExit as exc:  # argparse exits on --help and usage errors
        return int(exc.code or 0)
    return COMMANDS[args.command].run(args)


def _lazy(module: str, what: str) -> Callable[..., Any]:
    """A function that imports ``module`` only when called (keeps `embagents check` light)."""

    def call(*args: Any) -> Any:
        return getattr(importlib.import_module(module), what)(*args)

    return call


def _supervise_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("system", help="path of the system.py file")
    loud = parser.add_mutually_exclusive_group()
    loud.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    loud.add_argument("-q", "--quiet", action="store_true",
                      help="only warnings and errors on stderr (the answers are on stdout; `embagents logs` has the rest)")
    parser.add_argument("--offline", action="store_true",
                        help="embagents.compat recipes: replace model servers by the offline default models")
    parser.add_argument("--dashboard", action="store_true", help="serve the dashboard page and its JSON/WebSocket API")
    parser.add_argument("--dashboard-host", default="127.0.0.1", help="the dashboard's address (default: this machine only)")
    parser.add_argument("--dashboard-port", type=int, default=8420, help="the dashboard's port (default 8420)")
    parser.add_argument("--ready-file", metavar="PATH",
                        help="write PATH once every component is active (removed first, and at the end of the run)")
    parser.add_argument("--wait-subscribers", type=float, default=30.0, metavar="SECONDS",
                        help="the longest a component waits for the subscribers of its outputs before it is "
                             "activated anyway, with a warning (default 30)")


def _bench_arguments(parser: argparse.ArgumentParser) -> None:
    # The one definition: `python -m embagents.bench` takes it from COMMANDS["bench"] (the bench package is heavy).
    parser.add_argument("--json", metavar="FILE", help="also write the results as JSON to FILE")
    parser.add_argument("--quick", action="store_true", help="a smoke test: few iterations, 2 s idle window, no PASS/FAIL verdicts")
    parser.add_argument(
        "--only", nargs="+", metavar="NAME",
        help="run only cases matching NAME (a case name, glob, substring, transport or kind)",
    )
    parser.add_argument(
        "--minutes", type=float, metavar="N",
        help="how long the chaos case injects faults (default 1; 0.1 with --quick)",
    )
    parser.add_argument("--list", action="store_true", help="list the cases in run order and exit")
    parser.add_argument("--strict", action="store_true", help="exit with status 2 if a bar fails")


def _run_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--run", help="run id, system name or pid (default: the only live run)")
    parser.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the run to answer")


def _control(cmd: str) -> Command:
    """`embagents status|restart|stop`: requests to a live run's control endpoint."""

    def add(parser: argparse.ArgumentParser) -> None:
        _run_arguments(parser)
        if cmd == "status":
            parser.add_argument("--json", action="store_true", help="print the status as JSON")
            parser.add_argument(
                "--wait-ready", nargs="?", type=float, const=60.0, metavar="TIMEOUT",
                help="first wait until the run is ready, every component active (at most TIMEOUT s, default 60; "
                     "a run not started yet is waited for too); exit 1 if it is not",
            )
        if cmd == "restart":
            parser.add_argument("name", help="the actor to restart")

    def run(args: argparse.Namespace) -> int:
        from supervisor.client import control

        if cmd == "status":
            return _status(args)
        return control(cmd, run=args.run, timeout=args.timeout, as_json=getattr(args, "json", False),
                       name=getattr(args, "name", None), wait_ready_s=getattr(args, "wait_ready", None))

    helps = {
        "status": "a table of the running system: name, pid, state, restarts, uptime, CPU, memory, mailbox",
        "restart": "restart one actor of the running system",
        "stop": "stop the running system cleanly (reverse start order)",
    }
    return Command(add, run, helps[cmd])


def _status(args: argparse.Namespace) -> int:
    """`embagents status`: the supervisor's table, then the voice stages of the run's VoiceStage topics."""
    import json

    from actors import UnsafeFolder
    from embagents.tools.root import voice_lines
    from supervisor.client import ControlError, control, pick_run, request, wait_ready

    if args.json:  # one JSON object: the status with its "voice" key
        try:
            picked = (wait_ready(args.run, args.wait_ready) if args.wait_ready is not None else pick_run(args.run))
            reply = request(picked["run_dir"], {"cmd": "status"}, args.timeout)
            reply["voice"] = _voice_stages(picked["run_dir"], args.timeout)
        except (ControlError, UnsafeFolder) as exc:
            print(json.dumps({"ok": False, "error": str(exc)}))
            print(f"error: {exc}", file=sys.stderr)
            return 1
        print(json.dumps(reply, indent=2))
        return 0
    rc = control("status", run=args.run, timeout=args.timeout, wait_ready_s=args.wait_ready)
    if rc == 0:
        with contextlib.suppress(ControlError):
            for line in voice_lines(_voice_stages(pick_run(args.run)["run_dir"], args.timeout) or {}):
                print(line)
    return rc


def _voice_stages(run_dir: str, timeout: float) -> dict[str, Any] | None:
    """The run's ``voice_stages`` answer; None from a run that does not serve it."""
    from supervisor.client import ControlError, request

    try:
        reply = request(run_dir, {"cmd": "voice_stages"}, timeout)
        return {k: reply.get(k) for k in ("topics", "turns", "latest", "p50")}
    except ControlError as exc:
        if "unknown command" in str(exc):
            return None
        raise


def _publish_arguments(parser: argparse.ArgumentParser) -> None:
    _run_arguments(parser)
    parser.add_argument("topic", help="a topic of the running system, e.g. text_in")
    parser.add_argument("text", nargs="?", help="the message's `data` field (String, StreamingString)")
    parser.add_argument("--fields", metavar="JSON", help='other fields as a JSON object, e.g. \'{"data": "hi"}\'')


def _publish(args: argparse.Namespace) -> int:
    from actors import UnsafeFolder
    from embagents.publish import publish
    from supervisor.client import ControlError

    try:
        reply = publish(args.topic, args.text, args.fields, run=args.run, timeout=args.timeout)
    except (ControlError, UnsafeFolder, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"published {reply['type']} on {reply['topic']} (run {reply['run_id']}, system {reply['system']})")
    return 0


def _call_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--run", help="run id, system name or pid (default: the only live run)")
    parser.add_argument("--timeout", type=float, default=120.0, help="seconds to wait for the method to return")
    parser.add_argument("component", help="a component of the running system, e.g. vlm")
    parser.add_argument("method", help="its action, e.g. describe")
    parser.add_argument("args", nargs="*", help="arguments: JSON when they parse (3, true, [1, 2]), else strings")
    parser.add_argument("--kwargs", metavar="JSON", help='keyword arguments as a JSON object, e.g. \'{"query": "hi"}\'')
    parser.add_argument("-v", "--verbose", action="store_true", help="with an error the action raised: its traceback")


def _call(args: argparse.Namespace) -> int:
    import json

    from actors import UnsafeFolder
    from embagents.call import call, parse_args
    from supervisor.client import ControlError

    try:
        kwargs = json.loads(args.kwargs) if args.kwargs else {}
        if not isinstance(kwargs, dict):
            raise ValueError(f"--kwargs must be a JSON object, got {args.kwargs!r}")
        reply = call(args.component, args.method, parse_args(args.args), kwargs, run=args.run, timeout=args.timeout)
    except (ControlError, UnsafeFolder, ValueError) as exc:
        remote = (getattr(exc, "reply", None) or {}).get("traceback")
        if remote and args.verbose:
            print(f"remote traceback ({args.component}'s process):\n{remote.rstrip()}", file=sys.stderr)
        print(f"error: {exc}" + (" (-v: its traceback)" if remote and not args.verbose else ""), file=sys.stderr)
        return 1
    print(f"{args.component}.{args.method} -> {reply['result']!r}")
    return 0


def _register_runtime_commands() -> None:
    for cmd in ("status", "restart", "stop"):
        COMMANDS[cmd] = _control(cmd)
    COMMANDS["publish"] = Command(_publish_arguments, _publish, "publish a message on a topic of the running system")
    COMMANDS["call"] = Command(_call_arguments, _call, "run a component's action in the running system "
                               "(e.g. embagents call vlm describe camera 'what do you see?')")
    COMMANDS["supervise"] = Command(_supervise_arguments, _lazy("embagents.launch", "run"), "run a system.py under supervision")
    COMMANDS["keys"] = Command(
        _lazy("embagents.keys", "keys_arguments"), _lazy("embagents.keys", "run"),
        "make a CURVE key pair for model actors on another machine; prints the public key",
    )
    COMMANDS["serve-model"] = Command(
        _lazy("embagents.serve_model", "serve_model_arguments"), _lazy("embagents.serve_model", "run"),
        "serve a model actor to other machines over TCP with CURVE (only allowed keys get in)",
    )
    COMMANDS["serve-policy"] = Command(
        _lazy("embagents.tools.serve_policy_cli", "serve_policy_arguments"),
        _lazy("embagents.tools.serve_policy_cli", "run"),
        "serve a policy over openpi's WebSocket protocol (openpi clients drive our policies)",
    )
    for name, module, what, helptext in (
        ("topic", "topic_cli", "topic", "list, echo, measure (hz) and publish the topics of the running system"),
        ("logs", "logs_cli", "logs", "show (and follow with -f) one actor's log lines"),
        ("record", "record_cli", "record", "record the running system's topics to an MCAP file (a supervised recorder)"),
        ("play", "play", "play", "publish an MCAP recording into the running system (recorded timing, faster, stepped)"),
        ("view", "foxglove_view", "view", "serve the running system's topics to Foxglove (WebSocket, no ROS)"),
    ):
        COMMANDS[name] = Command(
            _lazy(f"embagents.tools.{module}", f"{what}_arguments"), _lazy(f"embagents.tools.{module}", "run"), helptext,
        )
    COMMANDS["bench"] = Command(
        _bench_arguments, _lazy("embagents.bench", "run"),
        "measure embagents side by side with raw pyzmq, multiprocessing queues and rclpy",
    )


_register_runtime_commands()


if __name__ == "__main__":
    sys.exit(main())
