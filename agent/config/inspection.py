"""The ``[inspection]`` and ``[camera]`` tables of a scenario: what counts as a capture.

A scenario with ``[inspection]`` is an inspection mission: every landmark is to be imaged
once by some drone, inside the camera's field of view, at an incidence no larger than
``max_incidence_deg`` and (under ``visibility = "occlusion"``) with a clear line of sight; at
a per-landmark vision (eq. 3.1) of at least ``quality``; and with a ``[camera]``, at a ground
sampling distance no larger than ``gsd_mm`` (:mod:`agent.core.camera`). A capture must meet
the spec tightened by ``aim_margin`` (GSD ≤ (1 − aim)·gsd_mm, vision ≥ quality·(1 + aim)),
so that a re-flight of the same viewpoints with position noise still meets it. With
``views`` = k > 1 every landmark is to be captured in k images whose viewing directions
differ pairwise by at least ``parallax_deg``: each landmark becomes k view landmarks, each
captured from its own view sector (:mod:`agent.core.views`, :mod:`agent.world.views`).
Without the table a mission is the thesis' coverage, unchanged.

.. code-block:: toml

    [inspection]
    quality = 0.3              # optional, in (0, 1]; 1 is head-on at d_opt (default 0.3,
                               # or no vision bound when gsd_mm is given)
    fov_deg = [80.0, 60.0]     # optional (not with [camera]): full horizontal and vertical
                               # field of view [deg]
    max_incidence_deg = 70.0   # optional, in (0, 90]: largest angle between the landmark's
                               # normal and the line to the camera [deg]
    gsd_mm = 2.0               # optional, needs [camera]: largest ground sampling distance
                               # per landmark [mm/px]
    aim_margin = 0.1           # optional, in [0, 0.5]: default 0.1 with gsd_mm, else 0
    views = 3                  # optional, 1..6: images per landmark (default 1)
    parallax_deg = 20.0        # optional, in (0, 90): least angle between two of its
                               # images' viewing directions [deg] (default 20)

    [camera]                   # the camera: its sensor, lens and image, or its field of view
    sensor_mm = [13.2, 8.8]    # sensor width, height [mm]
    focal_mm = 8.8             # focal length [mm]
    image_px = [5472, 3648]    # image width, height [px]
    # fov_deg = [73.7, 53.1]   # instead of sensor_mm and focal_mm: full fields of view [deg]
    trigger_s = 2.0            # optional: shortest interval between two images [s]
"""

from __future__ import annotations

import math

import msgspec

from agent.config.validation import Ctx
from agent.core.camera import Camera
from agent.core.inspection import CaptureSpec
from agent.core.views import DEFAULT_INCIDENCE, MAX_VIEWS, MIN_CONE, sector_cone, sector_fit
from agent.strategy.registry import StrategyName, strategy_of

#: The vision bound when an inspection is specified by its GSD alone: any clear view.
GSD_ONLY_QUALITY = 0.01
#: The default margin of a GSD spec (a fraction of gsd_mm).
GSD_AIM_MARGIN = 0.1


class InspectionTable(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    quality: float | None = None
    fov_deg: list[float] | None = None
    max_incidence_deg: float | None = None
    gsd_mm: float | None = None
    aim_margin: float | None = None
    views: int = 1
    parallax_deg: float = 20.0


class CameraTable(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    image_px: list[int]
    sensor_mm: list[float] | None = None
    focal_mm: float | None = None
    fov_deg: list[float] | None = None
    trigger_s: float = 0.0


def _pair(ctx: Ctx, path: str, value: list[float], what: str, hi: float = math.inf
          ) -> tuple[float, float]:
    if len(value) != 2 or not all(math.isfinite(x) and 0.0 < x < hi for x in value):
        raise ctx.fail(path, f"expected [width, height] {what}, got {value}")
    return float(value[0]), float(value[1])


def parse_camera(ctx: Ctx, table: CameraTable) -> Camera:
    """Check a ``[camera]`` table (one-line errors naming the field and the fix)."""
    at = "camera."
    w, h = _pair(ctx, at + "image_px", [float(x) for x in table.image_px], "in pixels, each > 0")
    px = (int(w), int(h))
    t = table.trigger_s
    if not (math.isfinite(t) and t >= 0.0):
        raise ctx.fail(at + "trigger_s", f"must be a non-negative number of seconds, got {t}")
    by_sensor = table.sensor_mm is not None or table.focal_mm is not None
    if by_sensor == (table.fov_deg is not None):
        raise ctx.fail("camera", "give either sensor_mm and focal_mm, or fov_deg (with "
                       "image_px in both cases)")
    if table.fov_deg is not None:
        fov = _pair(ctx, at + "fov_deg", table.fov_deg, "full angles in degrees, each in "
                    "(0, 180)", 180.0)
        return Camera.from_fov((math.radians(fov[0]), math.radians(fov[1])), px, t)
    if table.sensor_mm is None or table.focal_mm is None:
        raise ctx.fail(at + ("focal_mm" if table.focal_mm is None else "sensor_mm"),
                       "is missing; give sensor_mm and focal_mm together")
    sensor = _pair(ctx, at + "sensor_mm", table.sensor_mm, "in millimetres, each > 0")
    f = table.focal_mm
    if not (math.isfinite(f) and f > 0.0):
        raise ctx.fail(at + "focal_mm", f"must be a positive length in millimetres, got {f}")
    return Camera.from_sensor(sensor, f, px, t)


def parse_inspection(ctx: Ctx, table: InspectionTable, strategy: StrategyName,
                     camera: Camera | None = None, d_opt: float | None = None) -> CaptureSpec:
    """Check an ``[inspection]`` table with the scenario's camera (one-line errors naming
    the field and the fix)."""
    at = "inspection."
    gsd = table.gsd_mm
    if gsd is not None:
        if camera is None:
            raise ctx.fail(at + "gsd_mm", "needs the camera: add a [camera] table (sensor_mm, "
                           "focal_mm and image_px, or fov_deg and image_px)")
        if not (math.isfinite(gsd) and gsd > 0.0):
            raise ctx.fail(at + "gsd_mm", f"must be a positive number of millimetres per "
                           f"pixel, got {gsd}")
    q = table.quality if table.quality is not None else \
        (GSD_ONLY_QUALITY if gsd is not None else 0.3)
    if not (math.isfinite(q) and 0.0 < q <= 1.0):
        raise ctx.fail(at + "quality", f"must lie in (0, 1] (1 is head-on at d_opt), got {q}")
    aim = table.aim_margin if table.aim_margin is not None else \
        (GSD_AIM_MARGIN if gsd is not None else 0.0)
    if not (math.isfinite(aim) and 0.0 <= aim <= 0.5):
        raise ctx.fail(at + "aim_margin", f"must lie in [0, 0.5] (a fraction of the spec), "
                       f"got {aim}")
    fov = None if camera is None else camera.fov
    if table.fov_deg is not None:
        if camera is not None:
            raise ctx.fail(at + "fov_deg", "the [camera] table gives the field of view; "
                           "remove inspection.fov_deg")
        f = table.fov_deg
        if len(f) != 2 or not all(math.isfinite(x) and 0.0 < x < 180.0 for x in f):
            raise ctx.fail(at + "fov_deg", "expected [horizontal, vertical] full angles in "
                           f"degrees, each in (0, 180), got {f}")
        fov = (math.radians(f[0]), math.radians(f[1]))
    inc = table.max_incidence_deg
    if inc is not None and not (math.isfinite(inc) and 0.0 < inc <= 90.0):
        raise ctx.fail(at + "max_incidence_deg", f"must lie in (0, 90] degrees, got {inc}")
    if strategy_of(strategy).extends_thesis:  # tours replace the strategy's moves
        raise ctx.fail("strategy", f"an inspection mission plans capture tours; remove "
                       f"strategy = {strategy!r} or the [inspection] table")
    views, parallax = _views(ctx, table, None if inc is None else math.radians(inc))
    limit = None if gsd is None else gsd / 1000.0
    if limit is not None and camera is not None and d_opt is not None:
        reach = camera.range_for((1.0 - aim) * limit)
        if d_opt > reach:
            raise ctx.fail("d_opt", f"is {d_opt:g} m, farther than the {reach:.3g} m at which "
                           f"this camera meets inspection.gsd_mm = {gsd:g} (with aim_margin "
                           f"{aim:g}) head-on; set d_opt <= {reach:.3g}")
    return CaptureSpec(q, fov, None if inc is None else math.radians(inc), camera, limit, aim,
                       views=views, parallax=parallax)


def _views(ctx: Ctx, table: InspectionTable, max_incidence: float | None) -> tuple[int, float]:
    """``views`` and ``parallax_deg`` [rad] checked, and that their sectors fit within the
    incidence limit (:func:`agent.core.views.sector_cone`)."""
    at = "inspection."
    k, theta = table.views, table.parallax_deg
    if not 1 <= k <= MAX_VIEWS:
        raise ctx.fail(at + "views", f"must be an integer from 1 to {MAX_VIEWS} (images per "
                       f"landmark), got {k}")
    if not (math.isfinite(theta) and 0.0 < theta < 90.0):
        raise ctx.fail(at + "parallax_deg", f"must lie in (0, 90) degrees (the least angle "
                       f"between two images of a landmark), got {theta}")
    if k > 1 and sector_cone(k, math.radians(theta), max_incidence) is None:
        largest, smallest = sector_fit(k, math.radians(theta), max_incidence)
        within = f"max_incidence_deg = {math.degrees(max_incidence):g}" \
            if max_incidence is not None else \
            f"the default max_incidence_deg of {math.degrees(DEFAULT_INCIDENCE):g}"
        fixes = [f"parallax_deg <= {math.floor(math.degrees(largest) * 10) / 10:g}"] \
            if largest > 0.0 else []
        if smallest is not None:
            fixes.append(f"max_incidence_deg >= {math.ceil(math.degrees(smallest) * 10) / 10:g}")
        fixes.append("fewer views")
        raise ctx.fail(at + "views", f"{k} views {theta:g} deg apart leave view sectors "
                       f"narrower than {math.degrees(MIN_CONE):g} deg within {within}; use "
                       + " or ".join(fixes))
    return k, math.radians(theta)
