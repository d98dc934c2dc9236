"""The benchmark page, generated from ``docs/bench/*.json`` at build time.

Each file is a document ``embagents bench --json FILE`` wrote (``cases``, ``bars``, ``host``,
``wall_s``), optionally with an ``about`` object (``title``, ``date``, ``command``, ``machine``,
``source``). A dated run is committed as such a file, never typed into prose: the marker
``<!-- bench-runs -->`` in ``benchmarks.md`` is replaced by one section per file, newest
first (by ``about.date``, then file name), each with the ask round trips side by side and the
bars with their verdicts.

Example::

    >>> doc = {"bars": [{"name": "ask 6.2MB p50", "value": 0.82, "op": "<=", "target": 2.0,
    ...                  "unit": "ms", "pass": True}], "cases": []}
    >>> print(render_run("run.json", doc))  # doctest: +NORMALIZE_WHITESPACE
    ## run.json
    <BLANKLINE>
    `docs/bench/run.json`: 1 of 1 bars pass.
    <BLANKLINE>
    | bar | measured | target | |
    |---|---|---|---|
    | ask 6.2MB p50 | 0.82 ms | <= 2 ms | PASS |
    <BLANKLINE>
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from sphinx.application import Sphinx

MARKER = "<!-- bench-runs -->"
PAGE = "benchmarks"
SIZES = ((64, "64 B"), (1 << 20, "1 MiB"), (6_220_800, "6,220,800 B (1080p RGB)"))
TRANSPORTS = (("embagents", "embagents"), ("pyzmq", "raw pyzmq"), ("mp_queue", "mp.Queue"), ("rclpy", "rclpy"))


def _num(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, int) or (isinstance(v, float) and v.is_integer() and abs(v) >= 100):
        return f"{int(v):,}"
    return f"{v:g}"


def _us(v: float | None) -> str:
    if v is None:
        return "-"
    return f"{v:g} µs" if v < 1000 else f"{v / 1000:g} ms"


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def side_by_side(cases: list[dict[str, Any]], kind: str) -> list[str]:
    """A Markdown table of ``kind`` (ask, topic) p50 per payload size and transport, or nothing."""
    found = {(c.get("transport"), c.get("payload_bytes")): c for c in cases if c.get("kind") == kind}
    present = [(t, name) for t, name in TRANSPORTS if any(k[0] == t for k in found)]
    if not present:
        return []
    title = {"ask": "ask round trip p50", "topic": "topic one-way p50"}.get(kind, f"{kind} p50")
    out = [f"| {title} | " + " | ".join(n for _, n in present) + " |", "|---" * (len(present) + 1) + "|"]
    for size, label in SIZES:
        cells = [_us(found[(t, size)].get("p50_us")) if (t, size) in found else "-" for t, _ in present]
        if any(c != "-" for c in cells):
            out.append(f"| {label} | " + " | ".join(cells) + " |")
    return out + [""]


def render_run(name: str, doc: dict[str, Any]) -> str:
    """One run's section (Markdown): what was run where, side-by-side tables, the bars."""
    about = doc.get("about") or {}
    bars = doc.get("bars") or []
    graded = [b for b in bars if b.get("pass") is not None]
    lines = [f"## {about.get('title') or name}", ""]
    facts = [f"`docs/bench/{name}`"]
    if about.get("date"):
        facts.append(f"run on {about['date']}")
    if about.get("command"):
        facts.append(f"`{about['command']}`")
    if about.get("machine"):
        facts.append(about["machine"])
    elif (doc.get("host") or {}).get("cpus"):
        facts.append(f"{doc['host']['cpus']} CPUs")
    if doc.get("wall_s"):
        facts.append(f"{_num(doc['wall_s'])} s")
    summary = "; ".join(facts)
    if doc.get("quick"):
        summary += ". A quick run: a smoke test, the bars are not graded."
    elif graded:
        summary += f": {sum(1 for b in graded if b['pass'])} of {len(graded)} bars pass."
    lines += [summary, ""]
    if about.get("source"):
        lines += [f"From {about['source']}.", ""]
    cases = doc.get("cases") or []
    lines += side_by_side(cases, "ask") + side_by_side(cases, "topic")
    chaos = next((c for c in cases if c.get("name") == "chaos"), None)
    if chaos is not None:
        from embagents.bench.report import chaos_table

        lines += ["```text", chaos_table(chaos), "```", ""]
    if bars:
        lines += ["| bar | measured | target | |", "|---|---|---|---|"]
        for b in bars:
            unit = b.get("unit") or ""
            sep = "" if unit == "x" else " "
            measured = _num(b.get("value")) + (sep + unit if b.get("value") is not None else "")
            if b.get("note"):
                measured += f" ({b['note']})"
            verdict = {True: "PASS", False: "**FAIL**", None: "-"}[b.get("pass")]
            lines.append(f"| {_cell(b['name'])} | {_cell(measured)} | {_cell(b['op'])} {_num(b['target'])}{sep}{unit}"
                         f" | {verdict} |")
        lines.append("")
    for e in doc.get("errors") or []:
        lines.append(f"- `{e['name']}` failed: {_cell(str(e.get('error')))}")
    for s in doc.get("skipped") or []:
        lines.append(f"- `{s['name']}` skipped: {_cell(str(s.get('note')))}")
    return "\n".join(lines) + "\n"


def render_all(folder: Path) -> str:
    """Every run in ``folder``, newest first."""
    runs = []
    for path in sorted(folder.glob("*.json")):
        try:
            doc = json.loads(path.read_text())
        except ValueError as exc:
            raise ValueError(f"{path}: not a JSON document ({exc}); write it with embagents bench --json") from exc
        if not isinstance(doc, dict) or "bars" not in doc:
            raise ValueError(f"{path}: no 'bars': not an `embagents bench --json` document")
        runs.append((str((doc.get("about") or {}).get("date") or ""), path.name, doc))
    runs.sort(key=lambda r: (r[0], r[1]), reverse=True)
    return "\n".join(render_run(name, doc) for _, name, doc in runs)


def _source_read(app: Sphinx, docname: str, source: list[str]) -> None:
    if docname != PAGE:
        return
    if MARKER not in source[0]:
        raise ValueError(f"{PAGE}.md lacks the marker {MARKER} where the runs go")
    folder = Path(app.srcdir) / "bench"
    for path in folder.glob("*.json"):
        app.env.note_dependency(str(path))
    source[0] = source[0].replace(MARKER, render_all(folder))


def setup(app: Sphinx) -> dict[str, Any]:
    app.connect("source-read", _source_read)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
