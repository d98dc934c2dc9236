"""The documentation: README.md (the front door) and the Sphinx site in docs/.

- the site builds with warnings as errors (a broken internal link or a docstring that is not
  valid reST fails it), and `linkcheck` finds no broken internal link (external ones are
  ignored: CI reaches no outside host);
- the benchmark page is generated from docs/bench/*.json, each an `embagents bench --json`
  document whose verdicts follow from its values;
- every Python block of the README and the docs compiles; a block marked
  ``<!-- test: python -->`` runs, one marked ``<!-- test: embagents check -->`` passes
  `embagents check` as a system.py;
- every `embagents COMMAND` they name is a command (`embagents COMMAND --help` works);
- the README stays a front door: at most 250 lines.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PAGES = [ROOT / "README.md", *sorted(DOCS.rglob("*.md"))]
# A fenced block, possibly indented (inside a list item), with the marker line that may precede it.
_FENCE = re.compile(r"^(?:[ \t]*<!-- test: ([\w ]+) -->\n)?([ \t]*)```(\w*)[^\n]*\n(.*?)^\2```", re.S | re.M)


def code_blocks(lang: str) -> list[tuple[str, str | None, str]]:
    """(page, marker, code) of every fenced ``lang`` block of the README and the docs."""
    found = []
    for page in PAGES:
        for m in _FENCE.finditer(page.read_text()):
            if m[3] == lang:
                indent = len(m[2])
                code = "".join(line[indent:] for line in m[4].splitlines(keepends=True))
                found.append((str(page.relative_to(ROOT)), m[1], code))
    return found


def _sphinx(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "sphinx", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=600, env={**os.environ, "PYTHONPATH": str(ROOT)})


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The site built once into a temporary folder (html, and its doctrees for linkcheck)."""
    pytest.importorskip("sphinx", reason="the docs extra builds the site: pip install -e '.[docs]'")
    pytest.importorskip("myst_parser", reason="pip install -e '.[docs]'")
    out = tmp_path_factory.mktemp("site")
    proc = _sphinx("-W", "--keep-going", "-q", "-b", "html", "-d", str(out / "doctrees"), "docs", str(out / "html"))
    assert proc.returncode == 0, f"sphinx-build -W failed:\n{proc.stderr[-6000:]}"
    return out


def test_the_site_builds_with_warnings_as_errors(built: Path) -> None:
    html = built / "html"
    for page in ("index", "getting-started", "concepts/supervision", "guides/speech", "architecture", "benchmarks",
                 "api/components"):
        assert (html / f"{page}.html").is_file(), page
    # autodoc ran: a class of the API reference has its own anchor
    assert 'id="embagents.components.memory.Memory"' in (html / "api" / "components.html").read_text()


def test_linkcheck_finds_no_broken_internal_link(built: Path) -> None:
    proc = _sphinx("-W", "-q", "-b", "linkcheck", "-d", str(built / "doctrees"), "docs", str(built / "linkcheck"))
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]


def test_a_broken_internal_link_fails_the_build(tmp_path: Path) -> None:
    pytest.importorskip("myst_parser", reason="pip install -e '.[docs]'")
    src = tmp_path / "src"
    src.mkdir()
    (src / "conf.py").write_text('extensions = ["myst_parser"]\nmyst_heading_anchors = 4\n')
    (src / "index.md").write_text("# Home\n\nSee [the guide](guide.md#no-such-heading).\n\n"
                                  "```{toctree}\nguide\n```\n")
    (src / "guide.md").write_text("# Guide\n\n## A heading\n")
    proc = _sphinx("-W", "-q", "-b", "html", str(src), str(tmp_path / "out"))
    assert proc.returncode != 0 and "no-such-heading" in proc.stderr, proc.stderr


def test_every_bench_file_is_a_bench_json_document_whose_verdicts_follow_from_its_values() -> None:
    from embagents.bench.report import _bar

    files = sorted((DOCS / "bench").glob("*.json"))
    assert files, "docs/bench/ holds no run"
    for path in files:
        doc = json.loads(path.read_text())
        assert isinstance(doc.get("cases"), list) and isinstance(doc.get("bars"), list), path.name
        for bar in doc["bars"]:
            again = _bar(bar["name"], bar["value"], bar["op"], bar["target"], bar["unit"])
            if not doc.get("quick"):
                assert bar["pass"] == again["pass"], f"{path.name}: {bar['name']}: {bar['value']} {bar['op']} " \
                                                     f"{bar['target']} is not pass={bar['pass']}"


def test_the_benchmark_page_shows_every_bar_of_every_run(built: Path) -> None:
    import html

    # Sphinx's smart quotes turn ' into a typographic one.
    page = html.unescape((built / "html" / "benchmarks.html").read_text()).replace("\u2019", "'")
    for path in sorted((DOCS / "bench").glob("*.json")):
        assert f"docs/bench/{path.name}" in page
        for bar in json.loads(path.read_text())["bars"]:
            assert bar["name"].replace("`", "") in re.sub(r"<[^>]+>", "", page), (path.name, bar["name"])


def test_every_python_block_compiles() -> None:
    blocks = code_blocks("python")
    assert len(blocks) >= 6
    for page, _, code in blocks:
        try:
            compile(code, page, "exec")
        except SyntaxError as exc:
            pytest.fail(f"{page}: a Python block does not compile: {exc}\n{code}")


def test_the_marked_python_blocks_run(tmp_path: Path) -> None:
    marked = [(page, marker, code) for page, marker, code in code_blocks("python") if marker]
    assert {m for _, m, _ in marked} >= {"python", "embagents check"}, marked
    for i, (page, marker, code) in enumerate(marked):
        script = tmp_path / f"block{i}.py"
        script.write_text(code)
        argv = ["-m", "embagents.cli", "check", str(script)] if marker == "embagents check" else [str(script)]
        assert marker in ("python", "embagents check"), f"{page}: unknown marker {marker!r}"
        proc = subprocess.run([sys.executable, *argv], cwd=tmp_path, capture_output=True, text=True, timeout=120,
                              env={**os.environ, "PYTHONPATH": str(ROOT)})
        assert proc.returncode == 0, f"{page}: the block marked {marker!r} failed:\n{code}\n{proc.stdout}{proc.stderr}"


def named_commands() -> dict[str, str]:
    """Each `embagents COMMAND` named in code (spans, blocks) of the README and the docs -> a page naming it."""
    named: dict[str, str] = {}
    for page in PAGES:
        text = page.read_text()
        code = re.findall(r"`[^`\n]+`", text) + [m[4] for m in _FENCE.finditer(text)]
        code += [line for line in text.splitlines() if line.startswith("    ")]  # indented blocks
        for chunk in code:
            for cmd in re.findall(r"(?<![\w./\[-])(?<!from )embagents ([a-z][a-z-]*)\b", chunk):
                named.setdefault(cmd, str(page.relative_to(ROOT)))
    return named


def test_every_command_the_docs_name_exists_and_has_help() -> None:
    from embagents.cli import COMMANDS

    named = named_commands()
    assert {"supervise", "check", "status", "publish", "call", "topic", "bench"} <= set(named), named
    unknown = {c: p for c, p in named.items() if c not in COMMANDS}
    assert not unknown, f"named but not commands of embagents: {unknown}"
    script = ("import contextlib, io, sys\nfrom embagents.cli import main\nbad = []\n"
              f"for cmd in {sorted(named)!r}:\n"
              "    out = io.StringIO()\n"
              "    with contextlib.redirect_stdout(out):\n"
              "        code = main([cmd, '--help'])\n"
              "    if code != 0 or 'usage: embagents ' + cmd not in out.getvalue():\n"
              "        bad.append(cmd)\n"
              "print(bad)\nsys.exit(1 if bad else 0)\n")
    proc = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0, f"`embagents COMMAND --help` failed for {proc.stdout.strip()}\n{proc.stderr[-3000:]}"


def test_the_readme_is_a_front_door() -> None:
    lines = (ROOT / "README.md").read_text().count("\n")
    assert lines <= 250, f"README.md has {lines} lines; move sections into docs/ (a page per topic) and link them"
    readme = (ROOT / "README.md").read_text()
    # the two commands, unchanged (.ci/run runs the second)
    assert 'pip install -e ".[llm]" && embagents supervise examples/chat.py' in readme
    assert 'python -m pip install -e ".[all]" && python -m pytest' in readme
    for link in re.findall(r"\]\((docs/[^)#]+)", readme):
        assert (ROOT / link).exists(), f"README.md links {link}, which is not there"


def test_the_docs_extensions_doctests_pass() -> None:
    proc = subprocess.run([sys.executable, "-m", "pytest", "--doctest-modules", "-q", "-p", "no:cacheprovider",
                           "docs/_ext/benchpage.py", "docs/_ext/apipages.py"], cwd=ROOT, capture_output=True,
                          text=True, timeout=120, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0, proc.stdout[-3000:]
