"""``viscover import-plan RUN_DIR PLAN... --origin LAT,LON,ALT``: QGroundControl ``.plan``
files (those ``viscover export-plan`` wrote for an inspection run, perhaps edited since: a
viewpoint moved, an item deleted) read back, and for each landmark whether the plans' images
still capture it to the inspection's spec.

Reading a plan: :mod:`agent.flight.plan_images` (each image where the vehicle is, along the
camera's direction, as the autopilot flies the items).

The capture test is the inspection's (:func:`agent.core.inspection.capture_quality`: eq. 3.1
with the field of view, incidence, GSD and view sectors of the scenario's ``[inspection]``,
and with ``visibility = "occlusion"`` a clear line of sight through the structure,
:func:`agent.structure.sight_lines.sight_lines`), at the spec itself, without the margin
``aim`` the planners aim at (that margin is there for a re-flight's position errors); a
quality within 1e-9 of the threshold counts (the geodetic round trip of the plan).

Exit status: 0 every landmark the run captured is captured by the plans; 3 some are lost
(flown, the plans leave the inspection incomplete); 2 a user mistake. See docs/api.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agent.commands import kit
from agent.commands.export_plan import add_run_arguments, find_result, read_result
from agent.config.scenario import Scenario
from agent.errors import EXIT_INCOMPLETE, EXIT_OK, UsageError
from agent.flight.geodetic import Origin
from agent.flight.plan_images import PlanImages, plan_images

Array = NDArray[np.float64]

#: A capture at a quality this far below the threshold still counts (the plan's round trip).
TOLERANCE = 1e-9


#: The line for a missing ``--origin``.
NO_ORIGIN = ("--origin LAT,LON,ALT is required: the one export-plan was given (the geodetic "
             "position of the world frame's origin)")


def read_plan(path: Path, origin: Origin) -> PlanImages:
    """The images of the ``.plan`` file at ``path`` (named by its file name); a
    :class:`UsageError` in one line for a file that cannot be read as a plan."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise UsageError(f"{path}: cannot read it: {e.strerror or e}") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise UsageError(f"{path}: not a plan: cannot read it as JSON: {e}") from None
    try:
        return plan_images(doc, origin, path.name)
    except ValueError as e:
        raise UsageError(f"{path}: {e}") from None


@dataclass(frozen=True)
class PlanCaptures:
    """What a set of images captures of the scenario's landmarks (m,): ``captured`` (m,),
    each landmark's best ``quality`` (m,) among the images that capture it (0: none), and the
    index of that image (m,) (-1: none)."""

    captured: NDArray[np.bool_]
    quality: Array
    image: NDArray[np.intp]


def plan_captures(sc: Scenario, P: Array, V: Array) -> PlanCaptures:
    """Which landmarks of the inspection scenario ``sc`` (structure resolved) the images at
    positions P (K, 3) [m; world ENU] along unit V (K, 3) capture: the capture test of the
    module docstring, all images and landmarks in one batch."""
    from agent.core.inspection import capture_quality

    assert sc.inspection is not None, "not an inspection mission"
    spec = dataclasses.replace(sc.inspection, aim=0.0)
    m = len(sc.landmark_ids)
    Q = capture_quality(P, V, sc.q, sc.u, sc.d_opt, spec, sc.view_axis, sc.view_cos)
    good = Q >= spec.threshold - TOLERANCE
    if sc.visibility == "occlusion" and sc.structure is not None and good.any():
        from agent.structure.sight_lines import sight_lines
        from agent.world.structure import structure_model

        pairs = np.nonzero(good)
        good[pairs] = sight_lines(structure_model(sc.structure), P, sc.q, sc.u, pairs)
    if P.shape[0] == 0:
        return PlanCaptures(np.zeros(m, dtype=np.bool_), np.zeros(m), np.full(m, -1, np.intp))
    score = np.where(good, Q, -1.0)  # a capture's quality is at least the threshold, > 0
    best = np.argmax(score, axis=0)
    top = score[best, np.arange(m)]
    captured = top > 0.0
    return PlanCaptures(captured, np.where(captured, top, 0.0),
                        np.where(captured, best, -1).astype(np.intp))


@dataclass
class ImportReport:
    """The verdict of :func:`import_report`: per landmark (ids (m,) of the scenario, in its
    order) what the run did and what the plans do; :attr:`lost` the landmarks the run
    captured that no image of the plans captures."""

    ids: NDArray[np.int64]
    run: list[str]  #: captured, given up (reason), uncapturable (reason), not captured
    plan: list[str]  #: captured, lost, not captured
    quality: Array
    image: list[str | None]
    plans: list[PlanImages]
    spec: str

    @property
    def lost(self) -> list[int]:
        """Landmark ids the run captured and the plans do not."""
        return [int(i) for i, p in zip(self.ids, self.plan, strict=True) if p == "lost"]

    def summary(self) -> str:
        """One line: plans, images, what of the run's captures the plans still capture."""
        n_img = sum(len(p.images) for p in self.plans)
        run_got = sum(r == "captured" for r in self.run)
        kept = sum(r == "captured" and p == "captured"
                   for r, p in zip(self.run, self.plan, strict=True))
        more = sum(r != "captured" and p == "captured"
                   for r, p in zip(self.run, self.plan, strict=True))
        lost = self.lost
        line = (f"import-plan: {len(self.plans)} plan{'s' * (len(self.plans) != 1)}, {n_img} "
                f"image{'s' * (n_img != 1)}: {kept}/{run_got} landmarks the run captured are "
                f"captured at {self.spec}")
        if more:
            line += f", and {more} it did not"
        if lost:
            shown = ", ".join(map(str, lost[:20])) + (" ..." if len(lost) > 20 else "")
            return line + f"; {len(lost)} LOST: {shown}"
        return line + "; none lost"

    def to_json(self) -> dict[str, Any]:
        """The report as a JSON-able dict."""
        return {
            "summary": self.summary(), "spec": self.spec, "lost": self.lost,
            "plans": [{"name": p.name, "images": len(p.images), "warnings": p.warnings}
                      for p in self.plans],
            "landmarks": [{"id": int(i), "run": r, "plan": p,
                           "quality": None if q <= 0.0 else round(float(q), 6), "image": im}
                          for i, r, p, q, im in zip(self.ids, self.run, self.plan,
                                                    self.quality, self.image, strict=True)],
        }

    def table(self) -> str:
        """One aligned line per landmark: id, the run, the plans, best quality, its image."""
        rows = [("landmark", "run", "plans", "quality", "image")]
        rows += [(str(int(i)), r, p, "-" if q <= 0.0 else f"{q:.3f}", im or "-")
                 for i, r, p, q, im in zip(self.ids, self.run, self.plan, self.quality,
                                           self.image, strict=True)]
        width = [max(len(r[k]) for r in rows) for k in range(5)]
        return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, width, strict=True)).rstrip()
                         for r in rows)


def run_outcome(doc: dict[str, Any], ids: NDArray[np.int64]) -> list[str]:
    """What the run did with each landmark of ``ids``, from result.json's ``inspection``:
    ``captured``, ``given up (reason)``, ``uncapturable (reason)`` or ``not captured``."""
    ins = doc.get("inspection")
    if not isinstance(ins, dict):
        raise ValueError("no inspection block: import-plan needs an inspection mission's run")
    captured = np.isin(ids, np.asarray([int(x) for x in ins.get("captured") or []],
                                       dtype=np.int64))
    why = {**{int(k): f"uncapturable ({v})" for k, v in (ins.get("uncapturable") or {}).items()},
           **{int(k): f"given up ({v})" for k, v in (ins.get("given_up") or {}).items()}}
    return ["captured" if c else why.get(int(i), "not captured")
            for i, c in zip(ids, captured, strict=True)]


def import_report(sc: Scenario, doc: dict[str, Any], plans: Sequence[PlanImages]
                  ) -> ImportReport:
    """The plans' images against the run (``doc``: its result.json) on scenario ``sc``
    (structure resolved, an inspection; its landmarks those of the run)."""
    assert sc.inspection is not None, "not an inspection mission"
    ids = np.asarray(sc.landmark_ids, dtype=np.int64)
    images = [im for p in plans for im in p.images]
    P = np.array([im.position for im in images], dtype=np.float64).reshape(-1, 3)
    V = np.array([im.direction for im in images], dtype=np.float64).reshape(-1, 3)
    got = plan_captures(sc, P, V)
    run = run_outcome(doc, ids)
    ran = np.array([r == "captured" for r in run], dtype=np.bool_)
    plan = np.where(got.captured, "captured", np.where(ran, "lost", "not captured")).tolist()
    spec = dataclasses.replace(sc.inspection, aim=0.0).describe()
    return ImportReport(ids, run, [str(x) for x in plan], got.quality,
                        [images[k].label if k >= 0 else None for k in got.image.tolist()],
                        list(plans), spec)


def run_scenario_of(run: Path, result: Path, doc: dict[str, Any], path: str | None
                    ) -> Scenario:
    """The run's inspection scenario (structure resolved): ``--scenario`` (``path``), else
    the one a launched run's ``launch.json`` names; its landmarks must be the run's. A
    :class:`UsageError` in one line otherwise."""
    from agent.world.structure import resolve_structure

    want = [int(x) for x in doc.get("landmark_ids") or []]
    if path is not None:
        sc = resolve_structure(kit.scenario_arg(path, resolve=False))
        where = f"--scenario {path}"
    else:
        from agent.sim.run_inspection import find_scenario

        folder = result.parent.parent if result.parent.name == "report" else result.parent
        found, why = find_scenario(folder, {"landmark_ids": want}) \
            if (folder / "launch.json").is_file() else (None, "")
        if found is None:
            raise UsageError(f"{run}: the run names no scenario file{f' ({why})' if why else ''}"
                             ": give --scenario FILE (the run's scenario: its capture spec "
                             "and structure)")
        sc, where = found, f"scenario {found.name}"
    if sc.inspection is None:
        raise UsageError(f"{where}: not an inspection scenario (no [inspection])")
    if [int(x) for x in sc.landmark_ids] != want:
        raise UsageError(f"{where}: other landmarks than the run's result.json (is it the "
                         "run's scenario, with its seed?)")
    return sc


def register(sub: kit.Subparsers) -> None:
    """Add ``import-plan``."""
    p = sub.add_parser(
        "import-plan", help="check QGroundControl .plan files (export-plan's, perhaps edited) "
        "against an inspection run: which landmarks they still capture",
        description="Read the .plan files (one per drone, as viscover export-plan wrote them "
        "and as QGroundControl saves them after an edit: a viewpoint moved, an item "
        "deleted), take each image where the plan takes it (the position of the last "
        "navigation item, the direction of the last gimbal item), and test every landmark "
        "of the run against them with the inspection's own capture test (quality, field of "
        "view, incidence, GSD, view sectors, line of sight through the structure). Prints a "
        "summary line and a table per landmark (or --json). Exit status: 0 every landmark "
        "the run captured is captured by the plans, 3 some are lost, 2 a user mistake (a "
        "malformed plan, no scenario). See docs/api.md.")
    add_run_arguments(p, " (as given to export-plan)", origin_missing=NO_ORIGIN)
    p.add_argument("plans", nargs="+", metavar="PLAN", help=".plan files")
    p.add_argument("--scenario", metavar="FILE",
                   help="the run's scenario file, for its capture spec and structure "
                   "(default: the one a launched run's launch.json names)")
    p.add_argument("--json", action="store_true",
                   help="print the report as one JSON object instead of the table")
    p.set_defaults(func=cmd_import_plan)


def cmd_import_plan(args: argparse.Namespace) -> int:
    """``viscover import-plan RUN_DIR PLAN... --origin LAT,LON,ALT``."""
    run = Path(args.run_dir)
    result = find_result(run)
    doc = read_result(result)
    plans = [read_plan(Path(x), args.origin) for x in args.plans]
    sc = run_scenario_of(run, result, doc, args.scenario)
    try:
        rep = import_report(sc, doc, plans)
    except ValueError as e:
        raise UsageError(f"{result}: {e}") from None
    status = EXIT_INCOMPLETE if rep.lost else EXIT_OK
    if args.json:
        print(json.dumps({**rep.to_json(), "exit_status": status}, indent=1))
    else:
        print(rep.summary())
        print(rep.table())
    for p in plans:
        for w in p.warnings:
            print(f"viscover: warning: {w}", file=sys.stderr)
    return status
