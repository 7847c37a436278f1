"""The report's events, led by the mission's phases: take-off, trades, captures, landing,
then the failsafes summarised and the other notable events; every time on the result's
mission time axis τ [s] (:attr:`agent.sim.result.SimResult.tau_of_wall`).

A recording's events (``events.jsonl``) give the take-off and landing lines of the flying
agents (their ``flight`` events), the trades as each initiator committed them (``trade``
events) and the failsafes; the captures come from the result (``captures.jsonl``). A
simulation has no events: its phases come from the result alone (start, trades, captures,
end)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from agent.sim.result import SimResult
from agent.storage.events import (
    Event,
    Exited,
    Failsafe,
    Flight,
    Leave,
    MissionEvent,
    MocapHealth,
    Trade,
)

#: A flight phase line belongs to the take-off when it says one of these, to the landing ...
TAKEOFF = ("connected", "pre-flight", "armed", "took off", "taking off", "on station",
           "hovering")
LANDING = ("complete", "landing", "landed", "home", "disarmed")
#: event kinds listed under "Other events" (the rest is in events.jsonl), and the most rows
OTHER = ("restart", "fault", "violation", "command", "ack", "complete", "mission_complete",
         "join", "error", "process", "crash", "recording_end")
MAX_ROWS = 120
#: most landmark ids written in one capture's row
MAX_IDS = 12


@dataclass
class Section:
    """One table of the events part: title, header, rows of text cells, a CSS class per row,
    a note said above the table."""

    title: str
    head: list[str]
    rows: list[list[str]] = field(default_factory=list)
    classes: list[str] = field(default_factory=list)
    note: str = ""

    def add(self, row: list[Any], cls: str = "") -> None:
        """Append a row (cells as text)."""
        self.rows.append([str(x) for x in row])
        self.classes.append(cls)


def _t(x: float) -> str:
    """A time cell [s]."""
    return "-" if not np.isfinite(x) else f"{x:.1f}"


def _what(ev: MissionEvent) -> str:
    """An event's line without the process prefix (``viscover-flight-agent A: armed`` →
    ``armed``)."""
    text = ev.text
    if ": " in text:
        return text.split(": ", 1)[1]
    return text.removeprefix("viscover-flight-agent ")


def _ids(ids: list[int]) -> str:
    """Landmark ids, the first :data:`MAX_IDS` of them."""
    more = f", ... ({len(ids)})" if len(ids) > MAX_IDS else ""
    return ", ".join(map(str, ids[:MAX_IDS])) + more


def sections(events: Sequence[Event], result: SimResult) -> list[Section]:
    """Take-off, trades, captures, landing, failsafes (summary), other events."""
    tau = result.tau_of_wall(np.array([e.time for e in events], dtype=np.float64))
    take = Section("Take-off", ["τ [s]", "drone", "what"])
    trades = Section("Trades", ["τ [s]", "drones", "what"])
    caps = Section("Captures", ["τ [s]", "drone", "landmarks", "ids", "least quality"])
    land = Section("Landing", ["τ [s]", "drone", "what"])
    fails = Section("Failsafes", ["drone", "what", "times", "first τ [s]", "last τ [s]"])
    other = Section("Other events", ["τ [s]", "source", "kind", "what"])
    failed: dict[tuple[str, str], list[float]] = {}
    pairs: set[tuple[str, str, int, str | None]] = set()
    for ev, t in zip(events, tau, strict=True):  # a loop over events
        src, what = ev.source, _what(ev)
        low = what.lower()
        if isinstance(ev, Flight) and any(w in low for w in TAKEOFF):
            take.add([_t(t), src, what])
        elif (isinstance(ev, Flight) and any(w in low for w in LANDING)) \
                or isinstance(ev, (Leave, Exited)):
            land.add([_t(t), src, what])
        elif isinstance(ev, Trade):  # one row a trade: the initiator's, else the first side's
            a, b = sorted((src, ev.partner))
            key = (a, b, ev.count, ev.trade)
            if ev.role != "responder" and key not in pairs:
                pairs.add(key)
                trades.add([_t(t), f"{src} ⇄ {ev.partner}",
                            f"{src} gained {ev.gained}, gave {ev.given}"])
        elif isinstance(ev, Failsafe) or (isinstance(ev, MocapHealth) and ev.state != "ok"):
            failed.setdefault((src, what), []).append(float(t))
        elif ev.kind in OTHER:
            other.add([_t(t), src, ev.kind, ev.text], ev.level)
    if not events:  # a simulation: its phases from the result
        take.note = "Simulated: every drone starts at its initial pose at τ = 0 (no take-off)."
        end = (f"mission complete at τ = {result.t_complete:.1f} s" if result.t_complete
               is not None else "not complete")
        if result.inspection is not None:  # as every report of an inspection's end says it
            end = result.inspection.end(result.t_complete if result.complete
                                        else None).verdict()
        dur = float(result.times[-1]) if len(result.times) else 0.0
        land.note = f"Simulated: {end}; the simulation ended at τ = {dur:.1f} s (no landing)."
    if not trades.rows:
        for e in result.trades:  # the result's (a simulation's, or read from the counters)
            gain = "" if result.inspection is not None else f"; coverage {e.gain:+.3g}"
            trades.add([_t(e.t), f"{e.initiator} ⇄ {e.partner}",
                        f"{e.initiator} gave {e.to_partner}, got {e.to_initiator}{gain}"])
    for c in result.captures:  # a loop over capture events
        t = float(c.t) - result.clock_offsets.get(c.agent, 0.0)
        caps.add([_t(t), c.agent, len(c.landmarks), _ids(list(c.landmarks)),
                  f"{min(c.quality):.3f}" if c.quality else "-"])
    if result.inspection is not None:
        trades.note = ("An inspection: these are re-splits of the remaining work (the drones "
                       "do not trade by vision).")
    else:
        caps.note = "A coverage mission: no captures (see the landmark table's final poses)."
    for (src, what), ts in sorted(failed.items(), key=lambda kv: min(kv[1])):
        fails.add([src, what, len(ts), _t(min(ts)), _t(max(ts))], "warning")
    n = sum(len(ts) for ts in failed.values())
    fails.note = (f"{n} failsafe line(s) in all, grouped by drone and line." if n else
                  "None.")
    if len(other.rows) > MAX_ROWS:
        other.note = (f"The last {MAX_ROWS} of {len(other.rows)}; every event is in "
                      "events.jsonl.")
        other.rows, other.classes = other.rows[-MAX_ROWS:], other.classes[-MAX_ROWS:]
    for s in (take, trades, caps, land):
        if not s.rows and not s.note:
            s.note = "None recorded."
    return [take, trades, caps, land, fails, other]
