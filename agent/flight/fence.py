"""Fences: the mission space, less a margin, as the autopilot's inclusion fence (with an
altitude limit), the structure's bounding box as an exclusion polygon; uploaded with the
mission protocol (MAV_MISSION_TYPE_FENCE), read back to verify; breaches reported.

Items (common.xml MAV_CMD_NAV_FENCE_*; both autopilots store them: ArduPilot
MissionItemProtocol_Fence / AC_PolyFence_loader, PX4 mavlink_mission ``parse_mavlink_mission_
item``): one MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION (5001) per vertex and
MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION (5002) per vertex, param1 = the polygon's vertex
count, x/y = latitude/longitude [degE7], frame MAV_FRAME_GLOBAL (accepted by both; the
``*_INT`` frames are deprecated synonyms). Polygons are vertical columns: they have no
altitude, so the altitude limit is the flavour's parameter (ArduPilot FENCE_ALT_MAX with
FENCE_TYPE bit 1; PX4 GF_MAX_VER_DIST), in metres above home.

The exclusion column over the structure forbids flying above it too (a roof view needs
``exclude_structure=False``).

Breaches (:class:`FenceMonitor`): ArduPilot's FENCE_STATUS (breach_status 1, breach_count
going up, breach_type FENCE_BREACH 1 min altitude, 2 max altitude, 3 boundary) and its
SYS_STATUS GEOFENCE bit enabled but unhealthy; PX4 streams no FENCE_STATUS: its breach is
a failsafe (GF_ACTION's mode change, which the vehicle monitor sees as ``mode_changed``)
announced in a STATUSTEXT mentioning the geofence, which is reported here.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from agent.flight.driver_types import FlightError
from agent.flight.geodetic import Origin, enu_to_geodetic
from agent.flight.link import VehicleLink
from agent.flight.mission_protocol import MissionItem, MissionTransfer
from agent.flight.params import ParamClient
from agent.wire.mavlink import mavlink

_log = logging.getLogger(f"viscover.{__name__}")
Array = NDArray[np.float64]

BREACH_KINDS = {0: "none", 1: "min_alt", 2: "max_alt", 3: "boundary"}
_BREACH_TEXT = re.compile(r"(geo)?fence.*(breach|violat|exceed|outside)|"
                          r"(breach|violat|exceed|outside).*(geo)?fence", re.IGNORECASE)


@dataclass(frozen=True)
class FencePlan:
    """A fence for one mission: the inclusion polygon's and the exclusion polygon's vertices
    (latitude, longitude [degrees]), the altitude limit ``alt_max_m`` [m above the world
    origin], and the box it came from, ``lo``/``hi`` [m; world ENU] (the space less the
    margin: the set-point streamer's space)."""

    inclusion: tuple[tuple[float, float], ...]
    exclusion: tuple[tuple[float, float], ...]
    alt_max_m: float
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]

    def items(self) -> list[MissionItem]:
        """The MISSION_ITEM_INTs, inclusion first."""
        out = []
        for cmd, poly in ((mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, self.inclusion),
                          (mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION, self.exclusion)):
            out += [MissionItem(int(cmd), round(lat * 1e7), round(lon * 1e7),
                                param1=float(len(poly))) for lat, lon in poly]
        return out

    def alt_above_home(self, home_z: float = 0.0) -> float:
        """The altitude limit above home [m], home at height ``home_z`` [m; world ENU]."""
        return self.alt_max_m - home_z


def _corners(lo: Array, hi: Array) -> list[tuple[float, float]]:
    """The box's four horizontal corners (east, north), counter-clockwise."""
    return [(lo[0], lo[1]), (hi[0], lo[1]), (hi[0], hi[1]), (lo[0], hi[1])]


def fence_plan(lo: ArrayLike, hi: ArrayLike, origin: Origin, margin: float = 1.0,
               structure: tuple[ArrayLike, ArrayLike] | None = None,
               exclude_structure: bool = True) -> FencePlan:
    """The fence of the mission space [lo, hi] [m; world ENU] shrunk by ``margin`` [m]
    (inclusion polygon, altitude limit hi_z − margin), with the ``structure``'s bounding box
    (min and max corners [m; world ENU]) as the exclusion polygon. ValueError (one line) if
    the margin leaves no space, or the structure does not lie inside the fence."""
    lo_a = np.asarray(lo, dtype=np.float64) + margin
    hi_a = np.asarray(hi, dtype=np.float64) - margin
    if not (np.all(np.isfinite(lo_a)) and np.all(np.isfinite(hi_a))):
        raise ValueError("fence: the mission space must be bounded on every side")
    if np.any(hi_a[:2] <= lo_a[:2]) or hi_a[2] <= 0.0:
        raise ValueError(f"fence: a margin of {margin:g} m leaves no space inside the mission "
                         "space")

    def geo(points: list[tuple[float, float]]) -> tuple[tuple[float, float], ...]:
        lat, lon, _ = enu_to_geodetic([(e, n, 0.0) for e, n in points], origin)
        return tuple((float(a), float(b)) for a, b in zip(lat, lon, strict=True))

    exclusion: tuple[tuple[float, float], ...] = ()
    if structure is not None and exclude_structure:
        s_lo = np.asarray(structure[0], dtype=np.float64)
        s_hi = np.asarray(structure[1], dtype=np.float64)
        if np.any(s_lo[:2] <= lo_a[:2]) or np.any(s_hi[:2] >= hi_a[:2]):
            raise ValueError("fence: the structure's bounding box reaches the fence; shrink "
                             "the margin or give the structure room")
        exclusion = geo(_corners(s_lo, s_hi))
    return FencePlan(geo(_corners(lo_a, hi_a)), exclusion, float(hi_a[2]),
                     (float(lo_a[0]), float(lo_a[1]), float(lo_a[2])),
                     (float(hi_a[0]), float(hi_a[1]), float(hi_a[2])))


class FenceClient:
    """Installs a :class:`FencePlan` on the vehicle behind ``link`` and verifies it."""

    def __init__(self, link: VehicleLink, params: ParamClient) -> None:
        self.link = link
        self.params = params
        self.transfer = MissionTransfer(link, mavlink.MAV_MISSION_TYPE_FENCE)

    def close(self) -> None:
        """Stop listening."""
        self.transfer.close()

    def install(self, plan: FencePlan, home_z: float = 0.0, altitude: bool = True) -> None:
        """Upload the fence, read it back and compare; with ``altitude``, write the
        flavour's altitude limit (``plan.alt_above_home(home_z)`` [m]) and, on ArduPilot,
        the FENCE_TYPE bits that enforce polygon and altitude. FlightError (one line)."""
        items = plan.items()
        self.transfer.upload(items)
        back = self.transfer.download()
        if len(back) != len(items):
            raise FlightError(f"fence read back {len(back)} items, uploaded {len(items)}")
        for k, (a, b) in enumerate(zip(items, back, strict=True)):
            if not a.same_as(b):
                raise FlightError(f"fence read back differs at item {k}: command {b.command} "
                                  f"at ({b.x}, {b.y}), uploaded {a.command} at ({a.x}, {a.y})")
        if not altitude:
            return
        fl = self.link.flavour
        limit = plan.alt_above_home(home_z)
        got = self.params.set(fl.fence_alt_param, limit)
        if abs(got - limit) > 0.01:
            raise FlightError(f"{fl.fence_alt_param} is {got:g}, wanted {limit:g} m")
        name, bits = fl.fence_type_bits
        if name:
            self.params.ensure_bits(name, bits)
        _log.info("fence installed: %d inclusion and %d exclusion vertices, %s %.1f m",
                  len(plan.inclusion), len(plan.exclusion), fl.fence_alt_param, limit)


@dataclass(frozen=True)
class FenceBreach:
    """A breach the vehicle reported: when [s mission], from which message, its kind
    ('boundary', 'max_alt', 'min_alt', 'unknown'), the autopilot's breach count, the text."""

    t: float
    source: str
    kind: str
    count: int
    text: str = ""


class FenceMonitor:
    """Reports fence breaches of the vehicle behind ``link`` (see the module docstring):
    ``breaches`` (every report, in order), ``breached`` (now), ``on_breach`` (called on the
    receive thread for each new report)."""

    def __init__(self, link: VehicleLink, on_breach: Callable[[FenceBreach], None] | None = None
                 ) -> None:
        self.link = link
        self.on_breach = on_breach
        self.breaches: list[FenceBreach] = []
        self.breached = False
        self._count = 0
        self._sys_bad = False
        self._last_text = ("", -1e9)
        self._lock = threading.Lock()
        self._unsub = link.subscribe(("FENCE_STATUS", "SYS_STATUS", "STATUSTEXT"), self._on)

    def close(self) -> None:
        """Stop listening."""
        self._unsub()

    def _report(self, source: str, kind: str, count: int, text: str = "") -> None:
        b = FenceBreach(self.link.clock.now(), source, kind, count, text)
        with self._lock:
            self.breaches.append(b)
        _log.warning("fence breach (%s): %s%s", source, kind, f": {text}" if text else "")
        if self.on_breach is not None:
            self.on_breach(b)

    def _on(self, msg: Any) -> None:
        if msg.get_srcComponent() != self.link.cfg.target_component:
            return
        kind = msg.get_type()
        if kind == "FENCE_STATUS":
            status, count = int(msg.breach_status), int(msg.breach_count)
            new = status == 1 and (not self.breached or count > self._count)
            self.breached, self._count = status == 1, max(self._count, count)
            if new:
                self._report("FENCE_STATUS", BREACH_KINDS.get(int(msg.breach_type), "unknown"),
                             count)
        elif kind == "SYS_STATUS":
            bit = mavlink.MAV_SYS_STATUS_GEOFENCE
            bad = bool(int(msg.onboard_control_sensors_enabled) & bit) and \
                not int(msg.onboard_control_sensors_health) & bit
            if bad and not self._sys_bad and not self.link.flavour.fence_status_message:
                self.breached = True
                self._report("SYS_STATUS", "unknown", self._count)
            self._sys_bad = bad
        else:
            text = str(msg.text).strip("\x00 ")
            if int(msg.severity) > mavlink.MAV_SEVERITY_WARNING or not _BREACH_TEXT.search(text):
                return
            now = time.monotonic()
            if text == self._last_text[0] and now - self._last_text[1] < 2.0:
                return  # the autopilot repeats its warning
            self._last_text = (text, now)
            self.breached = True
            self._report("STATUSTEXT", "unknown", self._count, text)
