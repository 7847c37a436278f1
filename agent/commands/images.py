"""``viscover export-images RUN_DIR --out DIR [--origin LAT,LON,ALT]``: an inspection run's
images as the files a team takes home (:mod:`agent.mission.images`): ``images.csv`` (one row per
image: pose, geodetic position, ground sampling distance, landmarks in view), and with an origin
OpenDroneMap's ``geo.txt`` and ``captures.geojson``.

The run's ``result.json`` is found as ``viscover export-plan`` finds it (RUN_DIR/result.json,
else RUN_DIR/report/result.json; :func:`agent.commands.export_plan.find_result`). The camera
model for the GSD columns is the scenario's (``[camera]``: ``sc.inspection.camera``): the one of
``--scenario``, else the one result.json keeps (``inspection`` → ``numbers``), else the scenario
a launched run's folder names (``launch.json``, as ``viscover report`` finds it); without one
the GSD columns stay empty."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path
from typing import Any

from agent.commands import kit
from agent.commands.export_plan import add_run_arguments, find_result, read_result
from agent.core.camera import Camera
from agent.errors import UsageError
from agent.flight.geodetic import Origin
from agent.mission.images import image_records, write_image_files

log = logging.getLogger("viscover.export_images")


def register(sub: kit.Subparsers) -> None:
    """Add ``export-images``."""
    p = sub.add_parser(
        "export-images", help="write an inspection run's per-image records (images.csv) and "
        "the files photogrammetry reads (OpenDroneMap geo.txt, GeoJSON)",
        description="Read RUN_DIR/result.json (or RUN_DIR/report/result.json) of an inspection "
        "mission and write into --out: images.csv (one row per image: name <agent>_NNNN.jpg, "
        "time, drone, position [m; world ENU], yaw (compass heading), pitch (from the "
        "horizontal, negative down), roll, with --origin latitude, longitude and altitude, "
        "the ground sampling distance when the scenario has a camera model, the landmarks "
        "in view); with --origin also OpenDroneMap's geo.txt (EPSG:4326) and "
        "captures.geojson (one Point per image). See docs/images.md.")
    add_run_arguments(p, "; needed for geo.txt and captures.geojson")
    p.add_argument("--out", metavar="DIR", required=True, help="where to write the files")
    p.add_argument("--scenario", metavar="FILE",
                   help="the run's scenario file, for its camera model (default: the one a "
                   "launched run's launch.json names, if any)")
    kit.add_log_level(p)
    p.set_defaults(func=cmd_export_images)


def scenario_camera(path: str, run_scenario: object) -> tuple[Camera | None, str]:
    """The camera model of the scenario file at ``path`` and "", or None and one line saying
    why there is none (a scenario error is a usage error); a warning on stderr when the file
    names another scenario than the run's (``run_scenario``, result.json's ``scenario``)."""
    sc = kit.scenario_arg(path, resolve=False)
    if isinstance(run_scenario, str) and run_scenario and sc.name != run_scenario:
        print(f"viscover: warning: --scenario {path} is scenario {sc.name!r}, the run is of "
              f"{run_scenario!r}", file=sys.stderr)
    return _camera_of(sc.inspection, path)


def _camera_of(spec: Any, where: str) -> tuple[Camera | None, str]:
    """The ``camera`` of an inspection spec (``getattr``: older specs have none) and "", or
    None and why not."""
    if spec is None:
        return None, f"{where} is not an inspection scenario"
    camera = getattr(spec, "camera", None)
    if not isinstance(camera, Camera):
        return None, f"{where} has no camera model ([camera])"
    return camera, ""


def run_camera(result: Path, doc: dict[str, Any]) -> tuple[Camera | None, str]:
    """The camera model of the scenario a launched run's folder names (``launch.json``, the
    scenario checked to have the run's landmarks), or None and one line saying why not."""
    from agent.sim.run_inspection import find_scenario

    folder = result.parent.parent if result.parent.name == "report" else result.parent
    if not (folder / "launch.json").is_file():
        return None, "the run names no scenario (give --scenario FILE for its camera model)"
    sc, why = find_scenario(folder, {"landmark_ids": doc.get("landmark_ids") or []})
    if sc is None:
        return None, f"{why.removesuffix(': no inspection block')} (give --scenario FILE)"
    return _camera_of(sc.inspection, f"scenario {sc.name}")


def result_camera(doc: dict[str, Any]) -> Camera | None:
    """The camera model result.json keeps (``inspection`` → ``numbers``: pixel_angle,
    image_w, image_h, trigger_s), or None when it keeps none or a broken one."""
    numbers = (doc.get("inspection") or {}).get("numbers") or {}
    try:
        return Camera(float(numbers["pixel_angle"]),
                      (int(numbers["image_w"]), int(numbers["image_h"])),
                      float(numbers.get("trigger_s", 0.0)))
    except (KeyError, TypeError, ValueError):
        return None


def cmd_export_images(args: argparse.Namespace) -> int:
    """``viscover export-images RUN_DIR --out DIR``."""
    kit.setup_logging(args.log_level, "export-images")
    run = Path(args.run_dir)
    path = find_result(run)
    doc = read_result(path)
    where: Origin | None = args.origin
    if args.scenario:
        camera, why = scenario_camera(args.scenario, doc.get("scenario"))
    elif (camera := result_camera(doc)) is not None:
        why = ""
    else:
        camera, why = run_camera(path, doc)
    try:
        records = image_records(doc, camera=camera, origin=where)
    except ValueError as e:
        raise UsageError(f"{path}: {e}") from None
    out = kit.output_dir(args.out)
    try:
        paths = write_image_files(records, out)
    except OSError as e:
        raise UsageError(f"--out {out}: cannot write: {e.strerror or e}") from None
    log.info("%d images from %s", len(records), path)
    n = len(records)
    print(f"{out}/: {n} image{'s' * (n != 1)} ({', '.join(p.name for p in paths)})")
    if camera is None:
        print(f"GSD columns left empty: {why}")
    if where is None:
        print("geo.txt and captures.geojson need --origin LAT,LON,ALT (the geodetic position "
              "of the world frame's origin): only images.csv written")
    return 0
