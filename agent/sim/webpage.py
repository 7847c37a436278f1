"""The report page (``report.html``) that ``viscover report`` and ``viscover simulate`` both
write: one self-contained file (PNG figures embedded, no scripts, no external resources),
made to answer an inspection team's questions in order:

1. what was inspected, when, by which software: the scenario, the mission's date (UTC), the
   scenario digest (:func:`agent.config.digest.scenario_digest`), the software version;
2. how it ended: outcome, landmarks captured (or seen) of all, quality, trades, failsafes;
3. the time axis every time on the page and in the plots is on (mission time τ, explained);
4. the structure with its landmarks coloured by quality, the unseen ones marked, and the
   table of every landmark, worst first (:mod:`agent.sim.landmark_report`);
5. the events, led by the phases (:mod:`agent.sim.report_events`);
6. the other figures and, for a recording, what it holds.
"""

from __future__ import annotations

import base64
import html
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agent.sim.landmark_report import LandmarkTable
from agent.sim.report_events import Section
from agent.sim.resolution import Resolution
from agent.sim.result import completion_index

_STYLE = """body{font-family:system-ui,sans-serif;margin:2em;max-width:1100px;color:#222}
table{border-collapse:collapse;margin:0.5em 0 1.5em}td,th{border:1px solid #ccc;
padding:2px 8px;text-align:left;font-size:0.9em}th{background:#f3f3f3}
img{max-width:100%;border:1px solid #ddd;margin:0.5em 0}.warning{color:#a60}
.error,.bad{color:#b00;font-weight:bold}figure{margin:0 0 1.5em}.meta{color:#555}
td.num{text-align:right;font-variant-numeric:tabular-nums}"""
#: the landmark table's columns
LANDMARK_HEAD = ["id", "status", "quality", "distance [m]", "incidence [°]", "by", "τ [s]",
                 "position [m]", "note"]


@dataclass(frozen=True)
class ReportMeta:
    """What the page says of the run: its date (UTC), the scenario digest, the software
    version (of the report; of the recorder when it said), its source, the time axis."""

    date: str
    digest: str
    version: str
    source: str
    time_axis: str
    recorded_by: str | None = None


def _table(head: list[str], rows: list[list[Any]], classes: list[str] | None = None,
           attrs: str = "") -> str:
    """An HTML table of escaped cells (a header row if ``head``), rows styled by ``classes``."""
    cls = classes or [""] * len(rows)
    body = "".join(f'<tr class="{c}">' + "".join(f"<td>{html.escape(str(x))}</td>" for x in r)
                   + "</tr>" for r, c in zip(rows, cls, strict=True))
    top = "<tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>" if head else ""
    return f"<table{attrs}>{top}{body}</table>"


def _figure(path: Path, caption: str) -> str:
    """A PNG embedded as a data URI, with its caption."""
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (f'<figure><img alt="{html.escape(caption)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def _landmark_rows(table: LandmarkTable, q: np.ndarray) -> tuple[list[list[str]], list[str]]:
    """The landmark table's rows worst first (numbers formatted per column with numpy; the
    rows are then only joined)."""
    o = table.order()

    def fmt(a: np.ndarray, spec: str) -> np.ndarray:
        return np.where(np.isfinite(a), np.char.mod(spec, np.nan_to_num(a)), "-")

    pos = np.char.add(np.char.add(np.char.add(np.char.add(
        np.char.mod("%.2f", q[o, 0]), ", "), np.char.mod("%.2f", q[o, 1])), ", "),
        np.char.mod("%.2f", q[o, 2]))
    cols = [table.ids[o].astype(str), table.status[o], fmt(table.quality[o], "%.3f"),
            fmt(table.distance[o], "%.2f"), fmt(table.incidence[o], "%.1f"),
            np.where(table.by[o] == "", "-", table.by[o]), fmt(table.tau[o], "%.1f"), pos,
            table.reason[o]]
    good = table.good[o]
    return np.stack(cols, axis=1).tolist(), np.where(good, "", "bad").tolist()


def _summary(doc: dict[str, Any], table: LandmarkTable | None, fails: int, source: str,
             missing: str | None) -> list[list[str]]:
    """The summary rows."""
    checks = doc["checks"]
    ins = doc.get("inspection")
    done = (f"complete at τ = {doc['t_complete']:.1f} s" if doc["complete"]
            else f"NOT complete after {doc['duration']:.1f} s")
    if ins and ins.get("verdict"):  # an inspection: how it ended, as simulate says it
        done = ins["verdict"]
    rows = [["mission", f"{doc['scenario']} ({source})"]]
    if missing:
        return [*rows, ["outcome", f"{missing}; {doc['duration']:.1f} s recorded"]]
    rows.append(["outcome", done])
    if table is not None:
        good = table.good
        what = "captured" if table.source == "captures" else "seen at the final poses"
        q = table.quality[good]
        line = f"{int(good.sum())}/{good.size} {what}"
        if q.size:
            line += (f"; quality median {float(np.median(q)):.2f}, least "
                     f"{float(q.min()):.2f} (eq. 3.1: 1 = head-on at d_opt)")
        rows.append(["landmarks", line])
        missed = table.ids[np.isin(table.status, ("not captured", "unseen"))]
        if missed.size:
            rows.append(["NOT " + ("captured" if table.source == "captures" else "seen"),
                         ", ".join(map(str, missed[:40].tolist()))
                         + (f", ... ({missed.size})" if missed.size > 40 else "")])
    if ins:
        rows.append(["inspection", ins["line"]])
    else:
        rows.append(["coverage score (eq. 3.10)", coverage_cell(doc)])
        rows.append(["every landmark seen by its owner", "yes" if checks[
            "all_visible_to_owner"] else f"no: {checks['not_visible']}"])
    dist = checks["min_pairwise_distance"]
    rows += [["trades", str(len(doc["trades"]))],
             ["failsafes", str(fails)],
             ["closest approach of two drones", "-" if dist is None else f"{dist:.2f} m"],
             ["stayed inside the mission space", "yes" if checks["stayed_inside_space"]
              else f"no (by {checks['max_outside_space']:.2f} m)"]]
    return rows


def coverage_cell(doc: dict[str, Any]) -> str:
    """Coverage at the start → at completion (result.json's ``coverage`` [[t, c], ...] and
    ``t_complete``), and at the end when the run went on and it differs (a flight home)."""
    cov = doc["coverage"]
    if not cov:
        return "0 → 0"
    k = completion_index([t for t, _c in cov], doc.get("t_complete") if doc.get("complete")
                         else None)
    cell = f"{cov[0][1]:.4g} → {cov[k][1]:.4g}"
    if k < len(cov) - 1 and abs(cov[-1][1] - cov[k][1]) > 1e-9:
        cell += f" at completion; {cov[-1][1]:.4g} at the end (t = {cov[-1][0]:g} s)"
    return cell


def _resolution(res: Resolution) -> list[str]:
    """The resolution section: one row per group of landmarks, least margin first."""
    unit = "GSD [mm/px]" if res.gsd else "quality"

    def num(x: float, spec: str) -> str:
        return "–" if not np.isfinite(x) else format(x, spec)

    rows = [[r.name, r.landmarks, r.captured, r.left, r.landmarks - r.captured - r.left,
             num(r.median, ".3g"), num(r.worst, ".3g"), num(r.margin, "+.1%")]
            for r in res.rows]
    classes = ["bad" if r.left or (np.isfinite(r.margin) and r.margin < 0) else ""
               for r in res.rows]
    return ["<h2>Resolution</h2>", f"<p>{html.escape(res.note())}</p>",
            _table(["landmarks on", "landmarks", "captured", "left", "uncapturable",
                    f"median {unit}",
                    f"worst {unit}", "least margin"], rows, classes,
                   attrs=' id="resolution"')]


def page(doc: dict[str, Any], meta: ReportMeta, figures: list[tuple[Path, str]],
         table: LandmarkTable | None, q: np.ndarray, events: list[Section],
         kinds: dict[str, int], counts: dict[str, int],
         resolution: Resolution | None = None) -> str:
    """The report page of result.json's ``doc`` (module docstring): ``figures`` (the
    structure figure first when there is one), the landmark ``table`` (landmark positions
    ``q`` [m; world ENU]), the event sections, the count of each event kind and the
    recording's messages per topic (none for a simulation). A ``missing`` note in ``doc``
    is said first."""
    missing = doc.get("missing")
    fails = next((s for s in events if s.title == "Failsafes"), None)
    n_fail = 0 if fails is None else sum(int(r[2]) for r in fails.rows)
    version = f"viscover {meta.version}" + (
        f" (recorded by viscover {meta.recorded_by})"
        if meta.recorded_by and meta.recorded_by != meta.version else "")
    structure = [f for f in figures if f[0].name == "structure.png"]
    histogram = [f for f in figures if f[0].name == "resolution.png"]
    rest = [f for f in figures if f[0].name not in ("structure.png", "resolution.png")]
    parts = [
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        f"<title>viscover report: {html.escape(doc['scenario'])}</title>",
        f"<style>{_STYLE}</style></head><body>",
        f"<h1>viscover report: {html.escape(doc['scenario'])}</h1>",
        _table([], [["date (UTC)", meta.date], ["scenario digest", meta.digest],
                    ["software", version]], attrs=' class="meta" id="meta"'),
        f'<p class="error">{html.escape(missing)}</p>' if missing else "",
        "<h2>Summary</h2>",
        _table([], _summary(doc, table, n_fail, meta.source, missing), attrs=' id="summary"'),
        "<h2>Time axis</h2>", f"<p>{html.escape(meta.time_axis)}</p>"]
    if table is not None:
        rows, classes = _landmark_rows(table, q)
        src = ("each landmark's best capture" if table.source == "captures" else
               "the drones' final poses: the best camera for each landmark")
        parts += ["<h2>Landmarks</h2>", *(_figure(p, c) for p, c in structure),
                  f"<p>{len(rows)} landmarks, worst first; numbers from {src}. Distance from "
                  "the camera, incidence between the landmark's normal and the line to the "
                  "camera, quality of eq. 3.1.</p>",
                  _table(LANDMARK_HEAD, rows, classes, attrs=' id="landmarks"')]
    if resolution is not None:
        parts += [*_resolution(resolution), *(_figure(p, c) for p, c in histogram)]
    parts.append("<h2>Events</h2>")
    for s in events:
        parts.append(f"<h3>{html.escape(s.title)}</h3>")
        if s.note:
            parts.append(f"<p>{html.escape(s.note)}</p>")
        if s.rows:
            parts.append(_table(s.head, s.rows, s.classes))
    if kinds:
        parts.append("<p>Events by kind: " + html.escape(", ".join(
            f"{k} {n}" for k, n in sorted(kinds.items()))) + "</p>")
    parts += ["<h2>Figures</h2>", *(_figure(p, c) for p, c in rest)]
    if counts:
        parts += ["<h2>Recording</h2>",
                  _table(["topic", "messages"], [[t, n] for t, n in sorted(counts.items())])]
    parts.append("</body></html>")
    return "\n".join(parts)
