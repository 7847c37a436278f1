"""The ``[inspection]`` table of a scenario: what counts as a capture.

A scenario with this table is an inspection mission: every landmark is to be imaged once by
some drone at a per-landmark vision (eq. 3.1) of at least ``quality``, inside the camera's
field of view and at an incidence no larger than ``max_incidence_deg``; under
``visibility = "occlusion"`` with a clear line of sight. Without the table a mission is the
thesis' coverage, unchanged.

.. code-block:: toml

    [inspection]
    quality = 0.3              # optional, in (0, 1]; 1 is head-on at d_opt (default 0.3)
    fov_deg = [80.0, 60.0]     # optional: full horizontal and vertical field of view [deg]
    max_incidence_deg = 70.0   # optional, in (0, 90]: largest angle between the landmark's
                               # normal and the line to the camera [deg]
"""

from __future__ import annotations

import math

import msgspec

from agent.config.validation import Ctx
from agent.core.inspection import CaptureSpec
from agent.strategy.registry import StrategyName, strategy_of


class InspectionTable(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    quality: float = 0.3
    fov_deg: list[float] | None = None
    max_incidence_deg: float | None = None


def parse_inspection(ctx: Ctx, table: InspectionTable, strategy: StrategyName) -> CaptureSpec:
    """Check an ``[inspection]`` table (one-line errors naming the field and the fix)."""
    at = "inspection."
    q = table.quality
    if not (math.isfinite(q) and 0.0 < q <= 1.0):
        raise ctx.fail(at + "quality", f"must lie in (0, 1] (1 is head-on at d_opt), got {q}")
    fov = None
    if table.fov_deg is not None:
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
    return CaptureSpec(q, fov, None if inc is None else math.radians(inc))
