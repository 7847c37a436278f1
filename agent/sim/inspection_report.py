"""The inspection part of a report: ``result.json``'s ``captures`` and ``inspection`` and the
``captures.png`` plot (landmarks coloured by their best capture quality, the uncaptured ones
marked). Coverage missions get ``captures = []`` and ``inspection = null``.

``result.json``::

    captures      [{t, agent, landmarks (ids), position [m; world ENU], direction (unit
                    optical axis), right (unit image x axis, horizontal), quality (eq. 3.1
                    of each landmark)}] in time order
    inspection    {quality (least for a capture), captured (ids), capturable (count),
                   uncapturable {id: reason}, given_up {id: reason} (each capturable
                   landmark not captured: unreachable, blocked, battery or time;
                   agent.protocol.inspection_end), best_quality {id: best capture quality},
                   line ("captured N/M at quality >= q; K uncapturable (reasons)"),
                   verdict ("complete at t = X s" or "INCOMPLETE: G given up (...)")} or null

and the top-level ``complete`` of an inspection is its verdict's: every capturable landmark
captured.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec
import numpy as np

from agent.sim.result import CaptureEvent, SimResult

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def read_captures(path: Path) -> list[CaptureEvent]:
    """The captures of a run folder's ``captures.jsonl`` (empty if there is none; a line
    that is not a capture is skipped)."""
    out: list[CaptureEvent] = []
    if not path.is_file():
        return out
    for line in path.read_text(encoding="utf-8").splitlines():  # one capture per line
        try:
            out.append(msgspec.json.decode(line, type=CaptureEvent))
        except (msgspec.DecodeError, msgspec.ValidationError):
            continue
    return out


def best_quality(result: SimResult) -> dict[int, float]:
    """Each captured landmark's quality at its capture (its first, and only, capture)."""
    out: dict[int, float] = {}
    for c in result.captures:  # capture events, each with its landmarks
        out.update(zip(c.landmarks, c.quality, strict=True))
    return out


def inspection_document(result: SimResult) -> dict[str, Any]:
    """``captures`` and ``inspection`` of ``result.json``."""
    ins = result.inspection
    return {
        "captures": [{"t": float(c.t), "agent": c.agent, "landmarks": list(c.landmarks),
                      "position": list(c.position), "direction": list(c.direction),
                      "right": list(c.right), "quality": list(c.quality)} for c in result.captures],
        "inspection": None if ins is None else {
            "quality": ins.quality, "captured": list(ins.captured),
            "capturable": ins.capturable,
            "uncapturable": {str(k): v for k, v in ins.uncapturable.items()},
            "given_up": {str(k): v for k, v in ins.given_up.items()},
            "best_quality": {str(k): v for k, v in best_quality(result).items()},
            "line": ins.line(), "numbers": dict(ins.numbers), "parts": ins.parts,
            "verdict": ins.end(result.t_complete if result.complete else None).verdict()},
    }


def plot_captures(result: SimResult, path: Path) -> None:
    """3-D plot: landmarks coloured by best capture quality, uncaptured ones as red crosses,
    and the capture positions."""
    from matplotlib.figure import Figure

    fig: Figure = Figure(figsize=(8.0, 7.0))
    ax: Any = fig.add_subplot(projection="3d")
    best = best_quality(result)
    ids = np.asarray(result.landmark_ids)
    got = np.array([int(i) in best for i in ids], dtype=bool)
    qual = np.array([best.get(int(i), 0.0) for i in ids])
    q = result.q
    sc = ax.scatter(q[got, 0], q[got, 1], q[got, 2], c=qual[got], cmap="viridis", vmin=0.0,
                    vmax=1.0, marker="s", s=18, label="captured (colour: quality)")
    if (~got).any():
        ax.scatter(q[~got, 0], q[~got, 1], q[~got, 2], c="red", marker="x", s=30,
                   label="not captured")
    if result.captures:
        P = np.array([c.position for c in result.captures])
        ax.scatter(P[:, 0], P[:, 1], P[:, 2], c="0.4", marker=".", s=8, label="captures")
    fig.colorbar(sc, ax=ax, shrink=0.6, label="best capture quality (eq. 3.1)")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ins = result.inspection
    ax.set_title(f"{result.scenario}: {ins.line() if ins is not None else 'captures'}",
                 fontsize=8)
    ax.legend(loc="upper left", fontsize=8)
    fig.savefig(path, dpi=110)
