"""``viscover status`` on screen: a :class:`~agent.mission.watch.MissionView` as plain text
(logs, pipes, a terminal without :mod:`rich`), as a :mod:`rich` table refreshed in place, or as
the ``launch:`` lines ``viscover launch`` prints; each ends with the mesh's health when it is
gone or quiet ("mesh gone: no router/peers heard for 37 s")."""

from __future__ import annotations

from typing import Any

from agent.mission.watch import MissionView
from agent.wire.peer import Battery

HEADERS = ("drone", "phase", "landmarks", "vision", "trades ok/failed", "link", "last state",
           "mocap", "battery", "last fault")
#: shorter headers for a terminal table (the same columns)
SHORT = ("drone", "phase", "lm", "vision", "ok/failed", "link", "heard", "mocap", "battery",
         "last fault")


def battery_cell(b: Battery | None) -> str:
    """A drone's battery as its agent published it: '74 %, 15.31 V' (either alone when the
    autopilot says only one), 'unknown' without one (a kinematic agent, not reported yet)."""
    return "unknown" if b is None else b.summary()


def _cells(view: MissionView) -> list[tuple[str, ...]]:
    """The table's cells, one tuple per drone."""
    return [(r.id, r.phase + (" done" if r.done else ""), str(r.owned), f"{r.vision:.3f}",
             r.trades, r.link, r.heard, r.mocap, battery_cell(r.battery), r.fault)
            for r in view.rows]


def summary_line(view: MissionView) -> str:
    """One line: mission, elapsed wall and mission time, coverage (and the coverage at
    completion when it changed since by more than 1 %: a flight home), landmarks seen by owner
    (an inspection: captured); an inspection that ended with landmarks given up says so
    (``INCOMPLETE: G given up (...)``, as every report of its end)."""
    done = "complete" if view.complete else view.verdict or "in progress"
    unowned = f", {view.unowned} in flight" if view.unowned else ""
    if view.fenced:
        unowned += f"; lost (fenced) {', '.join(view.fenced)}, {view.orphaned} landmarks " \
            "orphaned"
    then = "" if view.coverage_complete is None or view.complete_t is None or abs(
        view.coverage - view.coverage_complete) <= 0.01 * abs(view.coverage_complete) else \
        f" ({view.coverage_complete:.4g} at completion, mission t {view.complete_t:.1f} s)"
    what = (f"coverage {view.coverage:.4g}{then}, landmarks seen by their owner {view.seen}, "
            f"not seen {view.not_seen}" if view.captured is None else
            f"captured {view.captured}/{view.seen + view.not_seen + view.unowned} landmarks"
            + (f", capture claims refused {view.refused_claims}" if view.refused_claims else ""))
    return (f"mission {view.mission}: {done}, {view.elapsed_s:.1f} s elapsed (wall), mission "
            f"t {view.mission_t:.1f} s, {what}{unowned}; violations "
            f"{len(view.violations)}, rejected payloads {view.rejected}")


def clocks_line(scale: float, flight: bool) -> str:
    """The two clocks of the status lines, and the report's axis, in one line (said once)."""
    whose = ("the ground station's simulation clock, which the flying agents follow" if flight
             else "each agent's own clock, from its start")
    return (f"times: elapsed (wall) is wall time since the first state heard; mission t is "
            f"the drones' mission clock ({whose}; {scale:g}x wall time); viscover report "
            "puts every drone on one mission-time axis τ, 0 at the first recorded sample")


def trades_cell(trades: str) -> str:
    """A row's trades for a line of text: "2 ok / 5 failed" ("-": none known yet)."""
    ok, sep, failed = trades.partition(" / ")
    return f"{ok} ok / {failed} failed" if sep else trades


def render_plain(view: MissionView) -> str:
    """The view as aligned plain-text lines (a header, one line per drone, a summary)."""
    rows = [HEADERS, *_cells(view)]
    width = [max(len(r[k]) for r in rows) for k in range(len(HEADERS))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, width, strict=True)).rstrip()
             for r in rows]
    lines.append(summary_line(view))
    lines += [f"VIOLATION {v}" for v in view.violations[-5:]]
    lines += [view.mesh] if view.mesh else []
    return "\n".join(lines)


def status_lines(view: MissionView, prefix: str = "") -> list[str]:
    """Each drone's phase, landmarks, vision, trades, link and the age of its last state,
    mocap, battery and last fault, then the mission's summary and the mesh's health: the rows
    of ``viscover status``, one line each (``viscover launch`` prints them every 2 s)."""
    rows = [f"{prefix}{r.id} {r.phase}{' done' if r.done else ''} {r.owned} lm vis "
            f"{r.vision:.3f} trades {trades_cell(r.trades)} link {r.link} {r.heard} mocap "
            f"{r.mocap} battery {battery_cell(r.battery)} fault {r.fault}" for r in view.rows]
    return [*rows, prefix + summary_line(view), *([prefix + view.mesh] if view.mesh else [])]


def render_rich(view: MissionView) -> Any:
    """The view as a :mod:`rich` renderable (a table captioned with the summary)."""
    from rich.console import Group
    from rich.table import Table
    from rich.text import Text

    table = Table(title=f"viscover mission {view.mission}", title_justify="left")
    for name in SHORT:
        table.add_column(name, no_wrap=name != "last fault", overflow="fold")
    for cells in _cells(view):
        style = "red" if cells[-1] != "-" and "violation" in cells[-1] else None
        table.add_row(*cells, style=style)
    parts: list[Any] = [table, Text(summary_line(view),
                                    style="green" if view.complete else
                                    "bold red" if view.verdict else "none")]
    parts += [Text(f"VIOLATION {v}", style="bold red") for v in view.violations[-5:]]
    parts += [Text(view.mesh, style="bold red")] if view.mesh else []
    return Group(*parts)
