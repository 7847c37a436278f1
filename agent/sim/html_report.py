"""``report.html`` and what it shows beyond :func:`agent.sim.report.write_report`'s files:
``landmarks.csv`` (every landmark's best quality, distance, incidence) and ``structure.png``
(the structure's mesh, landmarks coloured by quality, unseen ones marked; 3-D missions).
``viscover report`` (a recording) and ``viscover simulate`` both call :func:`write_html`, so
both write the same page (:mod:`agent.sim.webpage`)."""

from __future__ import annotations

import datetime
import json
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from agent.sim.landmark_report import landmark_table, plot_structure, write_csv
from agent.sim.report_events import sections
from agent.sim.resolution import plot_histogram, resolution_of
from agent.sim.result import SimResult
from agent.sim.webpage import ReportMeta, page
from agent.storage.events import Event

if TYPE_CHECKING:
    from agent.config.scenario import Scenario

CAPTIONS = {"structure.png": "The structure and its landmarks coloured by their best quality; "
                             "red crosses: not captured / unseen; grey pluses: uncapturable",
            "trajectories.png": "Trajectories (o start, * end)",
            "coverage.png": "Coverage score and each drone's vision over mission time τ, "
                            "trades marked",
            "partition.png": "Final partition: landmarks coloured by owner",
            "captures.png": "Captures: landmarks coloured by capture quality, the "
                            "uncaptured ones marked",
            "resolution.png": "Each captured landmark's finest ground sampling distance (or "
                              "capture quality) against the spec"}


def software_version() -> str:
    """The installed viscover's version ("unknown" when not installed as a package)."""
    try:
        return metadata.version("viscover")
    except metadata.PackageNotFoundError:
        return "unknown"


def utc(wall: float) -> str:
    """A wall time [s since the epoch] as ``YYYY-MM-DD HH:MM:SS UTC``."""
    return datetime.datetime.fromtimestamp(wall, datetime.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


def time_axis(result: SimResult) -> str:
    """The page's explanation of the mission time axis τ."""
    if result.wall_origin is None:
        return ("τ is simulated mission time [s] from the start of the simulation (τ = 0). "
                "Every time on this page and in the plots is on this axis.")
    s = result.time_scale
    return (f"τ is mission time [s], one axis for every drone: each drone's mission clock (a "
            f"flown drone follows the ground station's simulation clock, a kinematic agent "
            f"counts from its own start) is shifted so that the first recorded drone sample "
            f"is at τ = 0; the clocks ran at {s:.3g} mission seconds per wall second. Events, "
            f"logged in wall time w, are placed on it by τ = {s:.3g} × (w − "
            f"{utc(result.wall_origin)}); those before the first drone sample have τ < 0. "
            f"Every time on this page and in the plots is on this axis.")


def _mesh_model(sc: Scenario | None) -> Any:
    """The scenario's placed structure (mesh and line of sight), or None."""
    if sc is None or sc.structure is None:
        return None
    from agent.world.structure import structure_model

    return structure_model(sc.structure)


def write_html(result: SimResult, out: Path, paths: list[Path], *, source: str, date: str,
               digest: str, events: list[Event] | None = None,
               counts: dict[str, int] | None = None, scenario: Scenario | None = None,
               recorded_by: str | None = None, missing: str | None = None,
               plots: bool = True) -> list[Path]:
    """Write ``landmarks.csv``, ``structure.png`` (with ``plots``, a 3-D mission) and
    ``report.html`` into ``out`` next to ``paths`` (what write_report wrote, result.json
    first); returns ``paths`` with them added. Nothing of the landmarks for a recording
    ``missing`` its agent states."""
    events = events or []
    table = None
    if missing is None:
        model = _mesh_model(scenario)
        table = landmark_table(result, None if model is None else model.unoccluded)
        csv = out / "landmarks.csv"
        write_csv(table, result, csv)
        paths.append(csv)
        if plots and not result.planar:
            fig = out / "structure.png"
            mesh = None if model is None else (model.mesh.vertices, model.mesh.faces)
            plot_structure(result, table, mesh, fig)
            paths.append(fig)
    resolution = resolution_of(result) if missing is None else None
    if resolution is not None and plots and np.isfinite(resolution.value).any():
        fig = out / "resolution.png"
        plot_histogram(fig, resolution.value, resolution.limit, resolution.aim,
                       resolution.gsd)
        paths.append(fig)
    names = {p.name for p in paths}
    figures = [(p, CAPTIONS[p.name]) for p in paths if p.name in CAPTIONS
               and not (p.name == "captures.png" and "structure.png" in names)]
    figures.sort(key=lambda f: f[0].name != "structure.png")
    doc = json.loads((out / "result.json").read_text(encoding="utf-8"))
    kinds: dict[str, int] = {}
    for e in events:  # a loop over events
        kinds[e.kind] = kinds.get(e.kind, 0) + 1
    meta = ReportMeta(date=date, digest=digest, version=software_version(), source=source,
                      time_axis=time_axis(result), recorded_by=recorded_by)
    html_path = out / "report.html"
    html_path.write_text(page(doc, meta, figures, table, result.q, sections(events, result),
                              kinds, counts or {}, resolution), encoding="utf-8")
    paths.append(html_path)
    return paths
