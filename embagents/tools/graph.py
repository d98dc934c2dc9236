"""Draw a system (``embagents graph``): components as boxes, topics as ellipses.

Data flows left to right: each node sits one column right of the nodes that
feed it (longest-path layering; edges that close a cycle are drawn curving
below). Events are diamonds with dashed arrows to the components their
actions act on; ROS bridge endpoints are grey rounded boxes. SVG is written
in pure Python; PNG is drawn with OpenCV (``pip install
opencv-python-headless``), imported only when a PNG is asked for.

Example::

    >>> import tempfile, os
    >>> from embagents.components import Component
    >>> from embagents.msgs import String
    >>> from embagents.system import System
    >>> from embagents.topic import Topic
    >>> text = Topic("text", String)
    >>> system = System([Component(name="talker", outputs=[text]), Component(name="listener", inputs=[text])])
    >>> path = os.path.join(tempfile.mkdtemp(), "system.svg")
    >>> render_graph(system, path) == path
    True
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Callable
from typing import Any
from xml.sax.saxutils import escape

import attrs

from embagents.components.component import Component
from embagents.system import System

__all__ = ["FORMATS", "Layout", "edge_curve", "layout_system", "render_graph", "render_png", "render_svg"]

FORMATS = (".svg", ".png")

_COL_GAP = 70
_ROW_GAP = 26
_MARGIN = 30
_LINE_H = 16
_PAD_X = 14
_PAD_Y = 10
_CHAR_W = 7.3  # 12 px monospace in SVG
_BACK_ROOM = 40  # below the data nodes, where cycle edges loop

_COLORS = {  # fill, stroke (SVG hex)
    "component": ("#dbe9ff", "#2f5d9e"),
    "topic": ("#fff4d6", "#a57a00"),
    "event": ("#ffe0e0", "#b03030"),
    "ros": ("#e8e8e8", "#666666"),
}


@attrs.define
class Node:
    """A drawn node: center ``x``, ``y``, size ``w`` x ``h``, ``kind`` and text lines."""

    id: str
    kind: str
    lines: list[str]
    x: float = 0.0
    y: float = 0.0
    w: float = 0.0
    h: float = 0.0


@attrs.define
class Edge:
    """An arrow from node ``src`` to node ``dst``; ``style`` is "solid" or "dashed"."""

    src: str
    dst: str
    style: str = "solid"
    label: str = ""
    back: bool = False


@attrs.define
class Layout:
    """Positioned nodes and edges of a system drawing."""

    nodes: dict[str, Node]
    edges: list[Edge]
    width: float
    height: float


def _trigger_text(c: Component) -> str:
    kind = getattr(c, "trigger_kind", "none")
    if kind == "rate":
        return f"{c.rate_hz:g} Hz"
    if kind == "topics":
        return "on " + ", ".join(t.name for t in c.trigger_topics)
    if kind == "event" and c.trigger_event is not None:
        return f"on event {c.trigger_event.name}"
    return "server"


def _graph(system: System) -> tuple[dict[str, Node], list[Edge]]:
    nodes: dict[str, Node] = {}
    edges: list[Edge] = []

    def topic(name: str, type_name: str) -> str:
        nodes.setdefault(f"t:{name}", Node(f"t:{name}", "topic", [name, type_name]))
        return f"t:{name}"

    for c in system.components:
        cid = f"c:{c.name}"
        if cid in nodes:  # duplicate names: draw each, the check reports them
            cid = f"{cid}#{len(nodes)}"
        nodes[cid] = Node(cid, "component", [str(c.name), f"{type(c).__name__}, {_trigger_text(c)}"])
        for t in c.subscriptions:
            edges.append(Edge(topic(t.name, t.type_name), cid))
        for t in c.outputs:
            edges.append(Edge(cid, topic(t.name, t.type_name)))
    for m in getattr(system, "managers", ()):
        mid = f"c:{m.name}"
        lines = [m.name, f"Manager, {m.rate_hz:g} Hz"]
        if m.agents:
            lines.append("agents: " + ", ".join(f"{a.name}{' (isolated)' if a.isolated else ''}" for a in m.agents))
        nodes[mid] = Node(mid, "component", lines)
        for node in m.nodes:
            for t in node.subscriptions:
                edges.append(Edge(topic(t.name, t.type_name), mid))
            for t in node.outputs.values():
                edges.append(Edge(mid, topic(t.name, t.type_name)))
    for t in system.external:
        topic(t.name, t.type_name)
    by_name = {f"c:{c.name}" for c in system.components}
    for event, actions in system.events:
        eid = f"e:{event.name}"
        nodes.setdefault(eid, Node(eid, "event", ["event", event.name]))
        for t in event.topics:
            edges.append(Edge(topic(t.name, t.type_name), eid, "dashed"))
        for a in actions:
            if a.kind == "publish":
                edges.append(Edge(eid, topic(a.args["topic"], type(a.args["msg"]).__name__), "dashed", "publish"))
            elif a.component is not None and f"c:{a.component}" in by_name:
                edges.append(Edge(eid, f"c:{a.component}", "dashed", a.kind))
    for d in system.ros:
        internal, ros_topic = getattr(d, "topic", None), getattr(d, "ros_topic", None)
        if not isinstance(internal, str) or not isinstance(ros_topic, str):
            continue
        incoming = type(d).__name__ == "RosInput"
        rid = f"r:{'in' if incoming else 'out'}:{ros_topic}"
        nodes[rid] = Node(rid, "ros", ["ROS " + ("in" if incoming else "out"), ros_topic])
        tid = f"t:{internal}"
        if tid not in nodes:
            msg_type = getattr(d, "msg_type", None) if incoming else None
            topic(internal, msg_type.__name__ if isinstance(msg_type, type) else "?")
        edges.append(Edge(rid, tid) if incoming else Edge(tid, rid))
    return nodes, edges


def _layers(nodes: dict[str, Node], edges: list[Edge]) -> dict[str, int]:
    succ: dict[str, list[str]] = {n: [] for n in nodes}
    indeg = dict.fromkeys(nodes, 0)
    for e in edges:
        succ[e.src].append(e.dst)
        indeg[e.dst] += 1
    # Mark edges that close a cycle (DFS from sources first) so the rest is a DAG.
    state: dict[str, int] = {}
    back: set[tuple[str, str]] = set()
    for root in sorted(nodes, key=lambda n: indeg[n] > 0):
        if root in state:
            continue
        stack = [(root, iter(succ[root]))]
        state[root] = 1
        while stack:
            node, it = stack[-1]
            nxt = next(it, None)
            if nxt is None:
                state[node] = 2
                stack.pop()
            elif state.get(nxt) == 1:
                back.add((node, nxt))
            elif nxt not in state:
                state[nxt] = 1
                stack.append((nxt, iter(succ[nxt])))
    for e in edges:
        e.back = (e.src, e.dst) in back
    layer = dict.fromkeys(nodes, 0)
    deg = dict.fromkeys(nodes, 0)
    for e in edges:
        if not e.back:
            deg[e.dst] += 1
    ready = [n for n in nodes if deg[n] == 0]
    while ready:
        n = ready.pop()
        for e in edges:
            if e.src == n and not e.back:
                layer[e.dst] = max(layer[e.dst], layer[n] + 1)
                deg[e.dst] -= 1
                if deg[e.dst] == 0:
                    ready.append(e.dst)
    return layer


def layout_system(system: System, measure: Callable[[str], float] | None = None) -> Layout:
    """Place the nodes of ``system``; ``measure(text)`` is a text width in pixels.

    Data nodes (components, topics, ROS endpoints) are layered left to right;
    events go in a row below them, each under the nodes it connects, so
    their edges never hide a data edge.
    """
    measure = measure or (lambda text: len(text) * _CHAR_W)
    nodes, edges = _graph(system)
    data = {nid: n for nid, n in nodes.items() if n.kind != "event"}
    layer = _layers(data, [e for e in edges if e.src in data and e.dst in data])
    for n in nodes.values():
        n.w = max(measure(line) for line in n.lines) + 2 * _PAD_X
        n.h = len(n.lines) * _LINE_H + 2 * _PAD_Y
        if n.kind == "topic":  # text must fit inside the ellipse
            n.w *= 1.25
            n.h *= 1.2
        elif n.kind == "event":
            n.w *= 1.4
            n.h *= 1.4
    columns: list[list[Node]] = [[] for _ in range(max(layer.values(), default=0) + 1)]
    for nid, n in data.items():
        columns[layer[nid]].append(n)
    # Order each column by the mean row of its predecessors (fewer crossings).
    rank: dict[str, float] = {}
    for col in columns:
        def key(n: Node) -> float:
            preds = [rank[e.src] for e in edges if e.dst == n.id and e.src in rank]
            return sum(preds) / len(preds) if preds else float("inf")
        col.sort(key=key)
        for i, n in enumerate(col):
            rank[n.id] = i
    heights = [sum(n.h for n in col) + _ROW_GAP * (len(col) - 1) for col in columns]
    main_h = max(heights, default=0)
    x: float = _MARGIN
    for col, col_h in zip(columns, heights, strict=True):
        col_w = max((n.w for n in col), default=0)
        y = _MARGIN + (main_h - col_h) / 2
        for n in col:
            n.x, n.y = x + col_w / 2, y + n.h / 2
            y += n.h + _ROW_GAP
        x += col_w + _COL_GAP
    width = max(x - _COL_GAP + _MARGIN, 2 * _MARGIN)
    height = _MARGIN + main_h + (_BACK_ROOM if any(e.back for e in edges) else _ROW_GAP)
    events = [n for n in nodes.values() if n.kind == "event"]
    if events:
        for n in events:
            near = [nodes[e.dst if e.src == n.id else e.src].x for e in edges if n.id in (e.src, e.dst)]
            n.x = sum(near) / len(near) if near else _MARGIN + n.w / 2
        row_h = max(n.h for n in events)
        right: float = _MARGIN
        for n in sorted(events, key=lambda n: n.x):
            n.x = max(n.x, right + n.w / 2)  # no overlaps: push right
            n.y = height + row_h / 2
            right = n.x + n.w / 2 + _ROW_GAP
        width = max(width, right - _ROW_GAP + _MARGIN)
        height += row_h
    return Layout(nodes, edges, width, height + _MARGIN)


Point = tuple[float, float]


def edge_curve(layout: Layout, e: Edge) -> tuple[Point, Point, Point, Point]:
    """The cubic Bezier (start, control, control, end) an edge is drawn along."""
    a, b = layout.nodes[e.src], layout.nodes[e.dst]
    if e.back:  # loop below both nodes
        p1, p2 = (a.x, a.y + a.h / 2), (b.x, b.y + b.h / 2)
        low = max(p1[1], p2[1]) + _BACK_ROOM * 0.8
        return p1, (p1[0], low), (p2[0], low), p2
    vertical = "event" in (a.kind, b.kind)  # events sit in a row below: go straight down/up
    if not vertical and b.x - b.w / 2 > a.x + a.w / 2:  # b right of a: leave right, enter left
        p1, p2 = (a.x + a.w / 2, a.y), (b.x - b.w / 2, b.y)
        dx = max((p2[0] - p1[0]) / 2, 20)
        return p1, (p1[0] + dx, p1[1]), (p2[0] - dx, p2[1]), p2
    if not vertical and b.x + b.w / 2 < a.x - a.w / 2:  # b left of a (not a cycle): leave left, enter right
        p1, p2 = (a.x - a.w / 2, a.y), (b.x + b.w / 2, b.y)
        dx = max((p1[0] - p2[0]) / 2, 20)
        return p1, (p1[0] - dx, p1[1]), (p2[0] + dx, p2[1]), p2
    sign = 1 if b.y >= a.y else -1  # stacked: leave bottom/top, enter top/bottom
    p1, p2 = (a.x, a.y + sign * a.h / 2), (b.x, b.y - sign * b.h / 2)
    dy = max(abs(p2[1] - p1[1]) / 2, 20) * sign
    return p1, (p1[0], p1[1] + dy), (p2[0], p2[1] - dy), p2


def _sample(curve: tuple[Point, Point, Point, Point], n: int = 32) -> list[Point]:
    (x0, y0), (x1, y1), (x2, y2), (x3, y3) = curve
    out = []
    for i in range(n + 1):
        t = i / n
        u = 1 - t
        out.append((u**3 * x0 + 3 * u * u * t * x1 + 3 * u * t * t * x2 + t**3 * x3,
                    u**3 * y0 + 3 * u * u * t * y1 + 3 * u * t * t * y2 + t**3 * y3))
    return out


# --- SVG ------------------------------------------------------------------------------------


def _svg_node(n: Node) -> str:
    fill, stroke = _COLORS[n.kind]
    if n.kind == "topic":
        shape = f'<ellipse cx="{n.x:.1f}" cy="{n.y:.1f}" rx="{n.w / 2:.1f}" ry="{n.h / 2:.1f}"'
    elif n.kind == "event":
        pts = f"{n.x:.1f},{n.y - n.h / 2:.1f} {n.x + n.w / 2:.1f},{n.y:.1f} {n.x:.1f},{n.y + n.h / 2:.1f} {n.x - n.w / 2:.1f},{n.y:.1f}"
        shape = f'<polygon points="{pts}"'
    else:
        rx = 10 if n.kind == "ros" else 4
        shape = f'<rect x="{n.x - n.w / 2:.1f}" y="{n.y - n.h / 2:.1f}" width="{n.w:.1f}" height="{n.h:.1f}" rx="{rx}"'
    parts = [f'<g class="{n.kind}"><title>{escape(n.id)}</title>',
             f'{shape} fill="{fill}" stroke="{stroke}" stroke-width="1.5"/>']
    top = n.y - (len(n.lines) - 1) * _LINE_H / 2
    for i, line in enumerate(n.lines):
        weight = ' font-weight="bold"' if i == 0 and n.kind == "component" else ""
        parts.append(f'<text x="{n.x:.1f}" y="{top + i * _LINE_H:.1f}" text-anchor="middle" '
                     f'dominant-baseline="central"{weight}>{escape(line)}</text>')
    return "".join(parts) + "</g>"


def _svg_edge(layout: Layout, e: Edge) -> str:
    (x1, y1), (cx1, cy1), (cx2, cy2), (x2, y2) = curve = edge_curve(layout, e)
    d = f"M{x1:.1f},{y1:.1f} C{cx1:.1f},{cy1:.1f} {cx2:.1f},{cy2:.1f} {x2:.1f},{y2:.1f}"
    dash = ' stroke-dasharray="5,4"' if e.style == "dashed" else ""
    out = f'<path d="{d}" fill="none" stroke="#444" stroke-width="1.3"{dash} marker-end="url(#arrow)"/>'
    if e.label:
        mx, my = _sample(curve, 2)[1]
        out += f'<text x="{mx + 4:.1f}" y="{my - 4:.1f}" fill="#b03030">{escape(e.label)}</text>'
    return out


def render_svg(layout: Layout, title: str = "system") -> str:
    """The SVG document of a layout."""
    w, h = int(layout.width + 0.5), int(layout.height + 0.5)
    body = [_svg_edge(layout, e) for e in layout.edges] + [_svg_node(n) for n in layout.nodes.values()]
    return (
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" '
        'font-family="monospace" font-size="12">\n'
        f"<title>{escape(title)}</title>\n"
        '<defs><marker id="arrow" viewBox="0 0 10 10" refX="10" refY="5" markerWidth="8" markerHeight="8" '
        'orient="auto-start-reverse"><path d="M0,0 L10,5 L0,10 z" fill="#444"/></marker></defs>\n'
        f'<rect width="100%" height="100%" fill="white"/>\n' + "\n".join(body) + "\n</svg>\n"
    )


# --- PNG ------------------------------------------------------------------------------------


def _bgr(hex_color: str) -> tuple[int, int, int]:
    r, g, b = (int(hex_color[i : i + 2], 16) for i in (1, 3, 5))
    return b, g, r


def _import_cv2() -> Any:
    try:
        import cv2
    except ImportError as exc:
        raise RuntimeError("drawing a PNG needs OpenCV: pip install opencv-python-headless "
                           "(or write an .svg, which needs nothing)") from exc
    return cv2


def _arrow_head(cv2: Any, img: Any, tail: tuple[float, float], tip: tuple[float, float], s: float) -> None:
    import numpy as np

    d = np.subtract(tip, tail)
    d = d / (np.hypot(*d) or 1.0)
    n = np.array([-d[1], d[0]])
    base = np.asarray(tip) - 9 * d  # a fixed-size head, whatever the edge length
    pts = np.array([tip, base + 4 * n, base - 4 * n]) * s
    cv2.fillPoly(img, [pts.astype(np.int32)], (68, 68, 68), cv2.LINE_AA)


def render_png(system: System, path: str, scale: float = 2.0) -> None:
    """Draw ``system`` into the PNG file ``path`` with OpenCV."""
    cv2 = _import_cv2()
    import numpy as np

    font, font_scale = cv2.FONT_HERSHEY_SIMPLEX, 0.42

    def measure(text: str) -> float:
        return cv2.getTextSize(text, font, font_scale, 1)[0][0]

    layout = layout_system(system, measure)
    s = scale
    img = np.full((int(layout.height * s) + 1, int(layout.width * s) + 1, 3), 255, np.uint8)
    aa = cv2.LINE_AA

    def p(x: float, y: float) -> tuple[int, int]:
        return int(x * s), int(y * s)

    for e in layout.edges:
        curve = edge_curve(layout, e)
        pts = _sample(curve)
        ipts = [p(x, y) for x, y in pts]
        for i, (a, b) in enumerate(itertools.pairwise(ipts)):
            if e.style == "dashed" and i % 2:
                continue
            cv2.line(img, a, b, (68, 68, 68), max(1, int(s)), aa)
        _arrow_head(cv2, img, pts[-3], pts[-1], s)
        if e.label:
            mx, my = _sample(curve, 2)[1]
            cv2.putText(img, e.label, p(mx + 4, my - 4), font, font_scale * s, _bgr("#b03030"), 1, aa)
    for n in layout.nodes.values():
        fill, stroke = _bgr(_COLORS[n.kind][0]), _bgr(_COLORS[n.kind][1])
        if n.kind == "topic":
            for color, thick in ((fill, -1), (stroke, max(1, int(s)))):
                cv2.ellipse(img, p(n.x, n.y), (int(n.w / 2 * s), int(n.h / 2 * s)), 0, 0, 360, color, thick, aa)
        elif n.kind == "event":
            diamond = np.array([p(n.x, n.y - n.h / 2), p(n.x + n.w / 2, n.y), p(n.x, n.y + n.h / 2), p(n.x - n.w / 2, n.y)])
            cv2.fillPoly(img, [diamond], fill, aa)
            cv2.polylines(img, [diamond], True, stroke, max(1, int(s)), aa)
        else:
            a, b = p(n.x - n.w / 2, n.y - n.h / 2), p(n.x + n.w / 2, n.y + n.h / 2)
            cv2.rectangle(img, a, b, fill, -1)
            cv2.rectangle(img, a, b, stroke, max(1, int(s)), aa)
        top = n.y - (len(n.lines) - 1) * _LINE_H / 2
        for i, line in enumerate(n.lines):
            text = line.encode("ascii", "replace").decode()  # Hershey fonts are ASCII only
            thick = 2 if i == 0 and n.kind == "component" else 1
            tw, th = cv2.getTextSize(text, font, font_scale * s, thick)[0]
            org = (int(n.x * s - tw / 2), int((top + i * _LINE_H) * s + th / 2))
            cv2.putText(img, text, org, font, font_scale * s, (30, 30, 30), thick, aa)
    if not cv2.imwrite(path, img):
        raise OSError(f"could not write PNG {path!r} (does its folder exist?)")


def render_graph(system: System, path: str | os.PathLike[str]) -> str:
    """Draw ``system`` to ``path``: SVG or PNG by extension; returns the path written."""
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in FORMATS:
        raise ValueError(f"cannot draw a graph as {ext or 'a file without extension'!r} ({path}); "
                         f"use one of: {', '.join(FORMATS)}")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise FileNotFoundError(f"cannot write {path}: folder {folder} does not exist")
    if ext == ".svg":
        with open(path, "w", encoding="utf-8") as f:
            f.write(render_svg(layout_system(system), system.name))
    else:
        render_png(system, path)
    return path
