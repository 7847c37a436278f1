"""A short self-contained HTML page of a report (``viscover report``): the summary of
``result.json``, the plots embedded as PNG data, the mission's notable events and what the
recording holds. One file, no scripts, no external resources."""

from __future__ import annotations

import base64
import html
from pathlib import Path
from typing import Any

#: event kinds listed on the page (the rest is in events.jsonl), and the most rows shown
NOTABLE = ("trade", "restart", "fault", "failsafe", "violation", "command", "ack", "complete",
           "mission_complete", "leave", "mocap", "error", "process", "recording_end")
MAX_ROWS = 120

_STYLE = """body{font-family:system-ui,sans-serif;margin:2em;max-width:1100px;color:#222}
table{border-collapse:collapse;margin:0.5em 0 1.5em}td,th{border:1px solid #ccc;
padding:2px 8px;text-align:left;font-size:0.9em}th{background:#f3f3f3}
img{max-width:100%;border:1px solid #ddd;margin:0.5em 0}.warning{color:#a60}
.error{color:#b00;font-weight:bold}figure{margin:0 0 1.5em}"""


def _table(head: list[str], rows: list[list[Any]], classes: list[str] | None = None) -> str:
    """An HTML table of escaped cells (a header row if ``head``), rows styled by ``classes``."""
    cls = classes or [""] * len(rows)
    body = "".join(f'<tr class="{c}">' + "".join(f"<td>{html.escape(str(x))}</td>" for x in r)
                   + "</tr>" for r, c in zip(rows, cls, strict=True))
    top = "<tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>" if head else ""
    return f"<table>{top}{body}</table>"


def _figure(path: Path, caption: str) -> str:
    """A PNG embedded as a data URI, with its caption."""
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (f'<figure><img alt="{html.escape(caption)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def page(doc: dict[str, Any], figures: list[tuple[Path, str]], events: list[dict[str, Any]],
         counts: dict[str, int], source: str) -> str:
    """The report page of result.json's ``doc``, PNG figures, events and topic counts (a
    ``missing`` note in ``doc`` is said first, and what it lacks is shown as missing)."""
    missing = doc.get("missing")
    cov = doc["coverage"]
    c0, c1 = (cov[0][1], cov[-1][1]) if cov else (0.0, 0.0)
    checks = doc["checks"]
    done = (f"complete at t = {doc['t_complete']:.1f} s" if doc["complete"]
            else f"NOT complete after {doc['duration']:.1f} s")
    dist = checks["min_pairwise_distance"]
    summary = [
        ["mission", f"{doc['scenario']} ({source})"],
        ["outcome", done],
        ["coverage score (eq. 3.10)", f"{c0:.4g} → {c1:.4g}"],
        ["trades", str(len(doc["trades"]))],
        ["every landmark seen by its owner", "yes" if checks["all_visible_to_owner"]
         else f"no: {checks['not_visible']}"],
        ["closest approach of two agents", "-" if dist is None else f"{dist:.2f} m"],
        ["stayed inside the mission space", "yes" if checks["stayed_inside_space"]
         else f"no (by {checks['max_outside_space']:.2f} m)"],
    ]
    if missing:
        summary[1:5] = [["outcome", f"{missing}; {doc['duration']:.1f} s recorded"]]
    final = doc["final_partition"] or {}
    agents = [[a, ", ".join(map(str, final.get(a, []))) or "-",
               f"{doc['vision'][a][-1][1]:.4g}"
               if doc["vision"][a] else "-"] for a in doc["agents"]]
    notable = [e for e in events if e.get("kind") in NOTABLE]
    shown = notable[-MAX_ROWS:]
    rows = [[f"{float(e.get('t', 0.0)):.1f}", e.get("source", ""), e.get("kind", ""),
             e.get("text", "")] for e in shown]
    kinds: dict[str, int] = {}
    for e in events:
        kinds[str(e.get("kind"))] = kinds.get(str(e.get("kind")), 0) + 1
    more = (f"<p>{len(notable) - len(shown)} earlier notable events and every other event "
            "are in events.jsonl.</p>" if len(notable) > len(shown) else "")
    return "\n".join([
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        f"<title>viscover report: {html.escape(doc['scenario'])}</title>",
        f"<style>{_STYLE}</style></head><body>",
        f"<h1>viscover report: {html.escape(doc['scenario'])}</h1>",
        f'<p class="error">{html.escape(missing)}</p>' if missing else "",
        _table([], summary),
        "<h2>Final partition</h2>", _table(["agent", "landmarks", "vision"], agents),
        "<h2>Figures</h2>", *(_figure(p, c) for p, c in figures),
        "<h2>Events</h2>",
        "<p>" + html.escape(", ".join(f"{k} {n}" for k, n in sorted(kinds.items()))) + "</p>",
        _table(["t [s]", "source", "kind", "what"], rows,
               [str(e.get("level", "")) for e in shown]), more,
        "<h2>Recording</h2>",
        _table(["topic", "messages"], [[t, n] for t, n in sorted(counts.items())]),
        "</body></html>"])
