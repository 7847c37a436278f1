"""Fence storage (mission protocol) and breach behaviour of the simulated autopilot.

Mission protocol (mavlink.io mission protocol; ArduPilot libraries/GCS_MAVLink/
MissionItemProtocol.cpp, PX4 src/modules/mavlink/mavlink_mission.cpp), for every
mission_type (MISSION, FENCE, RALLY are stored; only the fence acts here, AUTO missions are
not flown): upload MISSION_COUNT → MISSION_REQUEST_INT(seq) ... MISSION_ITEM_INT → MISSION_ACK
(a count of 0 clears); an item out of sequence is answered by requesting the expected one
again; download MISSION_REQUEST_LIST → MISSION_COUNT, MISSION_REQUEST_INT → MISSION_ITEM_INT
(MISSION_REQUEST → MISSION_ITEM, degrees as floats); MISSION_CLEAR_ALL → MISSION_ACK.
Fence items (AC_PolyFence_loader.cpp): MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION /
_EXCLUSION (param1 = vertex count ≥ 3, the group's consecutive items), FENCE_CIRCLE_INCLUSION
/ _EXCLUSION (param1 = radius > 0 [m]), FENCE_RETURN_POINT; x, y lat/lon degE7 in a global
frame. A bad item ends the upload with its MAV_MISSION_RESULT (UNSUPPORTED command,
UNSUPPORTED_FRAME, INVALID_PARAM1, INVALID_PARAM5_X / 6_Y for latitude / longitude out of
range or not a number), a polygon group whose size disagrees with its param1 with INVALID;
the stored fence is then unchanged.

Breach (evaluated at 10 Hz on the EKF's estimate, not the truth, as the autopilots do):

* ArduPilot (libraries/AC_Fence/AC_Fence.cpp, ArduCopter/fence.cpp): enabled by FENCE_ENABLE
  or MAV_CMD_DO_FENCE_ENABLE (param1 0 off, 1 on, 2 off-floor-only; other values FAILED);
  FENCE_TYPE bits 1 max altitude (FENCE_ALT_MAX [m] above home), 2 circle (FENCE_RADIUS [m]
  around home), 4 polygons and circles uploaded (inside every inclusion, outside every
  exclusion), 8 min altitude (FENCE_ALT_MIN). A new breach while armed: disarm if landed,
  else FENCE_ACTION 0 report only, 1 RTL (or Land), 2 Land, 3 SmartRTL/RTL/Land (→ RTL), 4
  Brake (or Land), 5 SmartRTL or Land (→ Land); Land whenever the breach is more than 100 m
  (AC_FENCE_GIVE_UP_DISTANCE). FENCE_STATUS (1 Hz while enabled): breach_status,
  breach_count, breach_type (FENCE_BREACH_MAXALT / MINALT / BOUNDARY), breach_time [ms].
  SYS_STATUS's geofence health bit clears while breached.
* PX4 (src/modules/navigator/geofence_params.c; there is no FENCE_STATUS stream in
  src/modules/mavlink/streams): active while GF_ACTION ≠ 0, with the uploaded polygons and
  circles plus GF_MAX_HOR_DIST / GF_MAX_VER_DIST [m] from home (0: off). GF_ACTION 1
  warning, 2 Hold, 3 Return, 4 Terminate, 5 Land (:mod:`groundstation.vehicle.failsafe`). A
  breach shows as the mode change and a STATUSTEXT (this simulator's wording).
  MAV_CMD_DO_FENCE_ENABLE: UNSUPPORTED here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agent.wire.mavlink import mavlink as mav
from groundstation.vehicle import failsafe
from groundstation.vehicle.conventions import local_ne
from groundstation.vehicle.inbound import as_int

Array = NDArray[np.float64]
M = mav
VERTEX_IN, VERTEX_EX = M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, \
    M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION
CIRCLE_IN, CIRCLE_EX = M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION
FENCE_CMDS = {VERTEX_IN, VERTEX_EX, CIRCLE_IN, CIRCLE_EX, M.MAV_CMD_NAV_FENCE_RETURN_POINT}
GLOBAL_FRAMES = {M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_INT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                 M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
AP_ACTIONS = {1: "rtl", 2: "land", 3: "rtl", 4: "brake", 5: "land"}
PX4_ACTIONS = {1: "warn", 2: "hold", 3: "rtl", 4: "terminate", 5: "land"}
GIVE_UP_M = 100.0
MAX_ITEMS = 255  #: items per mission type (ArduPilot's fence storage holds at most 255)
CHECK_S = 0.1


def ardupilot_action(pt: Any, distance: float) -> str | None:
    """FENCE_ACTION's failsafe (None: report only); Land beyond :data:`GIVE_UP_M` [m]."""
    action = AP_ACTIONS.get(int(pt["FENCE_ACTION"]))
    return "land" if action is not None and distance > GIVE_UP_M else action


def px4_action(pt: Any) -> str | None:
    """GF_ACTION's failsafe (None: none)."""
    return PX4_ACTIONS.get(int(pt["GF_ACTION"]))


@dataclass
class Item:
    """One stored MISSION_ITEM_INT (lat/lon degE7 in x, y)."""

    seq: int
    frame: int
    command: int
    params: tuple[float, float, float, float]
    x: int
    y: int
    z: float
    current: int = 0
    autocontinue: int = 1


@dataclass
class Upload:
    """An upload in progress: its type, size, partner (system, component), items so far."""

    mission_type: int
    count: int
    partner: tuple[int, int]
    items: list[Item] = field(default_factory=list)


def polygon_outside(p: Array, poly: Array) -> bool:
    """Whether the point p (2,) [m; N, E] is outside polygon ``poly`` (n, 2) (even-odd
    rule, vectorised over the edges)."""
    a, b = poly, np.roll(poly, -1, axis=0)
    crosses = (a[:, 1] > p[1]) != (b[:, 1] > p[1])
    with np.errstate(divide="ignore", invalid="ignore"):
        x = a[:, 0] + (p[1] - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return int(np.count_nonzero(crosses & (p[0] < x))) % 2 == 0


def validate(item: Item, mission_type: int) -> int:
    """MAV_MISSION_RESULT of one item (module docstring)."""
    if mission_type != M.MAV_MISSION_TYPE_FENCE:
        return int(M.MAV_MISSION_ACCEPTED)
    if item.command not in FENCE_CMDS:
        return int(M.MAV_MISSION_UNSUPPORTED)
    if item.frame not in GLOBAL_FRAMES:
        return int(M.MAV_MISSION_UNSUPPORTED_FRAME)
    if not abs(item.x) <= 900_000_000:
        return int(M.MAV_MISSION_INVALID_PARAM5_X)
    if not abs(item.y) <= 1_800_000_000:
        return int(M.MAV_MISSION_INVALID_PARAM6_Y)
    p1 = item.params[0]
    if item.command in (VERTEX_IN, VERTEX_EX) and not (math.isfinite(p1) and p1 >= 3):
        return int(M.MAV_MISSION_INVALID_PARAM1)
    if item.command in (CIRCLE_IN, CIRCLE_EX) and not (math.isfinite(p1) and p1 > 0):
        return int(M.MAV_MISSION_INVALID_PARAM1)
    return int(M.MAV_MISSION_ACCEPTED)


def group_ok(items: list[Item]) -> bool:
    """Polygon vertex groups are consecutive items of one kind, as many as their param1."""
    i = 0
    while i < len(items):
        it = items[i]
        if it.command in (VERTEX_IN, VERTEX_EX):
            n = int(it.params[0])
            group = items[i:i + n]
            if len(group) != n or any(g.command != it.command or int(g.params[0]) != n
                                      for g in group):
                return False
            i += n
        else:
            i += 1
    return True


class Fence:
    """Mission storage of one autopilot and its fence (module docstring)."""

    def __init__(self, ap: Any) -> None:
        self.ap = ap
        self.stored: dict[int, list[Item]] = {}
        self.versions: dict[int, int] = {}  #: per mission type, counts what was stored
        self.upload: Upload | None = None
        self.enabled_cmd: bool | None = None  #: DO_FENCE_ENABLE's override (None: param)
        self.breaches = 0  #: current breach bits (FENCE_TYPE bits)
        self.breach_count = 0
        self.breach_time_ms = 0
        self._next_check = 0.0
        self._shapes: tuple[list[Array], list[Array], list[tuple[Array, float]],
                            list[tuple[Array, float]]] | None = None

    # -- mission protocol ---------------------------------------------------------------
    def on_message(self, msg: Any, t: float) -> None:
        """Every MISSION_* message addressed to the autopilot."""
        kind = msg.get_type()
        mtype = int(getattr(msg, "mission_type", 0))
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if kind == "MISSION_COUNT":
            self._on_count(int(msg.count), mtype, src)
        elif kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            self._on_item(msg, kind == "MISSION_ITEM", mtype, src)
        elif kind == "MISSION_REQUEST_LIST":
            self.ap.mav.mission_count_send(*src, len(self.stored.get(mtype, [])), mtype)
        elif kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            self._send_item(int(msg.seq), mtype, src, kind == "MISSION_REQUEST")
        elif kind == "MISSION_CLEAR_ALL":
            types = list(self.stored) if mtype == M.MAV_MISSION_TYPE_ALL else [mtype]
            for mt in types:
                self._commit(mt, [])
            self._ack(src, M.MAV_MISSION_ACCEPTED, mtype)

    def _ack(self, dst: tuple[int, int], result: int, mtype: int) -> None:
        self.ap.mav.mission_ack_send(dst[0], dst[1], result, mtype)

    def _on_count(self, count: int, mtype: int, src: tuple[int, int]) -> None:
        if count == 0:
            self._commit(mtype, [])
            self._ack(src, M.MAV_MISSION_ACCEPTED, mtype)
            return
        if count > MAX_ITEMS:
            self._ack(src, M.MAV_MISSION_NO_SPACE, mtype)
            return
        self.upload = Upload(mtype, count, src)
        self.ap.mav.mission_request_int_send(src[0], src[1], 0, mtype)

    def _on_item(self, m: Any, floats: bool, mtype: int, src: tuple[int, int]) -> None:
        up = self.upload
        if up is None or up.mission_type != mtype:
            return  # no upload of this type in progress: ignored
        seq = int(m.seq)
        if seq != len(up.items):
            self.ap.mav.mission_request_int_send(src[0], src[1], len(up.items), mtype)
            return
        x, y = (float(m.x), float(m.y))
        if floats and int(m.frame) in GLOBAL_FRAMES:  # MISSION_ITEM: degrees as floats
            x, y = x * 1e7, y * 1e7
        xi = as_int(x, (-(2**31), 2**31 - 1))
        yi = as_int(y, (-(2**31), 2**31 - 1))
        item = Item(seq, int(m.frame), int(m.command),
                    (float(m.param1), float(m.param2), float(m.param3), float(m.param4)),
                    2**31 if xi is None else xi, 2**31 if yi is None else yi, float(m.z),
                    int(m.current), int(m.autocontinue))
        result = validate(item, mtype)
        if result != M.MAV_MISSION_ACCEPTED:
            self.upload = None
            self._ack(src, result, mtype)
            return
        up.items.append(item)
        if len(up.items) < up.count:
            self.ap.mav.mission_request_int_send(src[0], src[1], len(up.items), mtype)
            return
        self.upload = None
        if mtype == M.MAV_MISSION_TYPE_FENCE and not group_ok(up.items):
            self._ack(src, M.MAV_MISSION_INVALID, mtype)
            return
        self._commit(mtype, up.items)
        self._ack(src, M.MAV_MISSION_ACCEPTED, mtype)

    def _send_item(self, seq: int, mtype: int, dst: tuple[int, int], floats: bool) -> None:
        items = self.stored.get(mtype, [])
        if not 0 <= seq < len(items):
            self._ack(dst, M.MAV_MISSION_INVALID_SEQUENCE, mtype)
            return
        it = items[seq]
        if floats:
            scale = 1e-7 if it.frame in GLOBAL_FRAMES else 1.0
            self.ap.mav.mission_item_send(dst[0], dst[1], seq, it.frame, it.command, it.current,
                                          it.autocontinue, *it.params, it.x * scale,
                                          it.y * scale, it.z, mtype)
        else:
            self.ap.mav.mission_item_int_send(dst[0], dst[1], seq, it.frame, it.command,
                                              it.current, it.autocontinue, *it.params, it.x,
                                              it.y, it.z, mtype)

    def _commit(self, mtype: int, items: list[Item]) -> None:
        self.stored[mtype] = list(items)
        self.versions[mtype] = self.versions.get(mtype, 0) + 1
        if mtype == M.MAV_MISSION_TYPE_FENCE:
            self._shapes = None

    # -- geometry -----------------------------------------------------------------------
    def shapes(self) -> tuple[list[Array], list[Array], list[tuple[Array, float]],
                              list[tuple[Array, float]]]:
        """(inclusion polygons, exclusion polygons, inclusion circles, exclusion circles)
        in [m; N, E] from the EKF origin."""
        if self._shapes is None:
            inc: list[Array] = []
            exc: list[Array] = []
            cin: list[tuple[Array, float]] = []
            cex: list[tuple[Array, float]] = []
            items = self.stored.get(M.MAV_MISSION_TYPE_FENCE, [])
            i = 0
            while i < len(items):
                it = items[i]
                ne = local_ne(self.ap.origin, it.x, it.y)
                if it.command in (VERTEX_IN, VERTEX_EX):
                    n = int(it.params[0])
                    poly = np.array([local_ne(self.ap.origin, g.x, g.y) for g in items[i:i + n]])
                    (inc if it.command == VERTEX_IN else exc).append(poly)
                    i += n
                    continue
                if it.command in (CIRCLE_IN, CIRCLE_EX):
                    (cin if it.command == CIRCLE_IN else cex).append((ne, it.params[0]))
                i += 1
            self._shapes = (inc, exc, cin, cex)
        return self._shapes

    def outside_zones(self, p: Array) -> bool:
        """The point p (2,) [m; N, E] breaks the uploaded polygons / circles."""
        inc, exc, cin, cex = self.shapes()
        return (any(polygon_outside(p, poly) for poly in inc)
                or any(not polygon_outside(p, poly) for poly in exc)
                or any(float(np.hypot(*(p - c))) > r for c, r in cin)
                or any(float(np.hypot(*(p - c))) <= r for c, r in cex))

    # -- breach -------------------------------------------------------------------------
    @property
    def enabled(self) -> bool:
        """The fence is checked (module docstring; the flavour's rule)."""
        return bool(self.ap.flavour.fence_enabled(self))

    def command_enable(self, p: list[float]) -> int:
        """MAV_CMD_DO_FENCE_ENABLE, as the flavour takes it."""
        return int(self.ap.flavour.fence_enable_command(self, p))

    def ardupilot_enabled(self) -> bool:
        """ArduPilot: DO_FENCE_ENABLE's last word, else FENCE_ENABLE."""
        if self.enabled_cmd is not None:
            return self.enabled_cmd
        return int(self.ap.params_table["FENCE_ENABLE"]) == 1

    def ardupilot_enable(self, p: list[float]) -> int:
        """ArduPilot's MAV_CMD_DO_FENCE_ENABLE (param1 0 off, 1 on, 2 off-floor-only)."""
        how = as_int(p[0], (0, 0xFFFF))
        if how is None:
            return int(M.MAV_RESULT_DENIED)
        if how not in (0, 1, 2):
            return int(M.MAV_RESULT_FAILED)
        self.enabled_cmd = how == 1
        return int(M.MAV_RESULT_ACCEPTED)

    def check(self, t: float) -> None:
        """Evaluate the fence (at most every CHECK_S [s]) and act on a new breach."""
        if t < self._next_check:
            return
        self._next_check = t + CHECK_S
        if not self.enabled:
            self.breaches = 0
            return
        p, _, _, _ = self.ap.estimate()
        home = self.ap.home_ned()
        bits, dist = self.ap.flavour.fence_bits(self, p, home)
        new = bits & ~self.breaches
        cleared = self.breaches and not bits
        self.breaches = bits
        if cleared:
            failsafe.statustext(self.ap, M.MAV_SEVERITY_NOTICE, "Fence breach cleared")
        if not new:
            return
        self.breach_count += 1
        self.breach_time_ms = int(t * 1000) & 0xFFFFFFFF
        failsafe.statustext(self.ap, M.MAV_SEVERITY_CRITICAL, "Geofence breached")
        if not self.ap.armed:
            return
        action = self.ap.flavour.fence_action(self.ap.params_table, dist)
        if action is not None:
            failsafe.act(self.ap, action, t, "fence")
        else:
            self.ap.event(t, "failsafe_fence_report")

    def ardupilot_bits(self, p: Array, home: Array) -> tuple[int, float]:
        """ArduPilot's breach bits by FENCE_TYPE and how far out [m] (altitude, circle)."""
        pt = self.ap.params_table
        ftype, alt = int(pt["FENCE_TYPE"]), float(home[2]) - float(p[2])
        r = float(np.hypot(*(p[:2] - home[:2])))
        bits, dist = 0, 0.0
        if ftype & 1 and alt > float(pt["FENCE_ALT_MAX"]):
            bits, dist = bits | 1, max(dist, alt - float(pt["FENCE_ALT_MAX"]))
        if ftype & 2 and r > float(pt["FENCE_RADIUS"]):
            bits, dist = bits | 2, max(dist, r - float(pt["FENCE_RADIUS"]))
        if ftype & 4 and self.outside_zones(p[:2]):
            bits |= 4
        if ftype & 8 and alt < float(pt["FENCE_ALT_MIN"]) and not self.ap.landed:
            bits |= 8
        return bits, dist

    def px4_bits(self, p: Array, home: Array) -> tuple[int, float]:
        """PX4's breach bits: GF_MAX_VER_DIST, GF_MAX_HOR_DIST and the uploaded zones."""
        pt = self.ap.params_table
        hor, ver = float(pt["GF_MAX_HOR_DIST"]), float(pt["GF_MAX_VER_DIST"])
        bits = 0
        if ver > 0 and float(home[2]) - float(p[2]) > ver:
            bits |= 1
        if hor > 0 and float(np.hypot(*(p[:2] - home[:2]))) > hor:
            bits |= 2
        if self.outside_zones(p[:2]):
            bits |= 4
        return bits, 0.0

    def status_fields(self) -> tuple[int, int, int, int]:
        """FENCE_STATUS (breach_status, breach_count, breach_type, breach_time [ms])."""
        kind = M.FENCE_BREACH_NONE
        if self.breaches & 8:
            kind = M.FENCE_BREACH_MINALT
        if self.breaches & 1:
            kind = M.FENCE_BREACH_MAXALT
        if self.breaches & 6:
            kind = M.FENCE_BREACH_BOUNDARY
        return int(self.breaches != 0), self.breach_count, kind, self.breach_time_ms
