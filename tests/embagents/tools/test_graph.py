"""`embagents graph`: SVG and PNG drawings of a system."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from embagents.cli import main
from embagents.components import Component
from embagents.events import Event, on, restart
from embagents.msgs import Image, String
from embagents.system import System
from embagents.tools.graph import layout_system, render_graph
from embagents.topic import Topic

SVG = "{http://www.w3.org/2000/svg}"


def demo_system() -> System:
    image, labels, answer = Topic("camera/image", Image), Topic("labels", String), Topic("answer", String)
    camera = Component(name="camera", outputs=[image], trigger=15.0)
    detector = Component(name="detector", inputs=[image], outputs=[labels], trigger=image)
    talker = Component(name="talker", inputs=[labels, answer], outputs=[answer], trigger=labels)  # a cycle
    ev = Event("person_seen", on(labels).field("data") == "person")
    return System([camera, detector, talker], events={ev: restart("talker")}, name="demo")


def test_layout_flows_left_to_right():
    layout = layout_system(demo_system())
    x = {nid: n.x for nid, n in layout.nodes.items()}
    assert x["c:camera"] < x["t:camera/image"] < x["c:detector"] < x["t:labels"] < x["c:talker"] < x["t:answer"]
    back = [(e.src, e.dst) for e in layout.edges if e.back]
    assert back == [("t:answer", "c:talker")]
    for n in layout.nodes.values():  # everything inside the canvas
        assert 0 <= n.x - n.w / 2 and n.x + n.w / 2 <= layout.width
        assert 0 <= n.y - n.h / 2 and n.y + n.h / 2 <= layout.height


def test_svg_is_valid_and_shows_every_node(tmp_path):
    path = render_graph(demo_system(), tmp_path / "system.svg")
    root = ET.parse(path).getroot()
    assert root.tag == f"{SVG}svg"
    texts = [t.text for t in root.iter(f"{SVG}text")]
    for name in ("camera", "detector", "talker", "camera/image", "labels", "answer", "person_seen", "restart"):
        assert name in texts
    assert "Component, 15 Hz" in texts and "Component, on labels" in texts
    assert len(list(root.iter(f"{SVG}rect"))) == 1 + 3  # background + components
    assert len(list(root.iter(f"{SVG}ellipse"))) == 3
    assert len(list(root.iter(f"{SVG}path"))) >= 8


def test_png_decodes_and_has_drawing(tmp_path):
    cv2 = pytest.importorskip("cv2")
    path = render_graph(demo_system(), str(tmp_path / "system.png"))
    img = cv2.imread(path)
    assert img is not None and img.shape[0] > 100 and img.shape[1] > 400
    ink = np.any(img < 200, axis=2).mean()
    assert 0.01 < ink < 0.5  # something drawn, not a blank or a black image
    blue = np.all(np.abs(img.astype(int) - (255, 233, 219)) < 3, axis=2).sum()  # component fill (BGR)
    assert blue > 1000


def test_unknown_extension_is_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match=r"'\.jpg'.*use one of: \.svg, \.png"):
        render_graph(demo_system(), tmp_path / "system.jpg")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        render_graph(demo_system(), tmp_path / "missing" / "system.svg")


def test_cli_graph(tmp_path, capsys):
    sys_py = tmp_path / "system.py"
    sys_py.write_text(
        "from embagents.components import Component\nfrom embagents.msgs import String\n"
        "from embagents.system import System\nfrom embagents.topic import Topic\n"
        "t = Topic('t', String)\n"
        "system = System([Component(name='a', outputs=[t]), Component(name='b', inputs=[t], trigger=t)])\n"
    )
    out = tmp_path / "g.svg"
    assert main(["graph", str(sys_py), "-o", str(out)]) == 0
    assert f"wrote {out}" in capsys.readouterr().out and out.stat().st_size > 500
    assert main(["graph", str(sys_py), "-o", str(tmp_path / "g.gif")]) == 1
    assert "use one of" in capsys.readouterr().err


def test_a_manager_is_drawn_with_its_rate_agents_and_node_topics() -> None:
    from embagents.manager import Agent, Manager, Node
    from embagents.msgs import String
    from embagents.system import System
    from embagents.tools.graph import layout_system
    from embagents.topic import Topic

    heard, said = Topic("heard", String), Topic("said", String)
    boss = Manager(20, name="boss", nodes=[Node("io", subscribe=[heard], publish=[said])],
                   agents=[Agent("planner", dict, isolated=True)])
    layout = layout_system(System([], managers=[boss], external=[heard]))
    assert layout.nodes["c:boss"].lines == ["boss", "Manager, 20 Hz", "agents: planner (isolated)"]
    assert {(e.src, e.dst) for e in layout.edges} == {("t:heard", "c:boss"), ("c:boss", "t:said")}
