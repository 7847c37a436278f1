"""Pose from the autopilot (``--pose autopilot``): the vehicle's own estimate (GNSS/RTK
outdoors) as the pose provider the set-point stream and the planner fly on, instead of
motion capture.

Inputs (from the vehicle's autopilot component):

* LOCAL_POSITION_NED (x, y, z [m], vx, vy, vz [m/s]; local NED at the EKF origin) with the
  latest ATTITUDE (roll, pitch, yaw [rad]; R_NED←FRD, ZYX), or ODOMETRY (frame_id
  MAV_FRAME_LOCAL_NED; q = R_NED←FRD; velocity in LOCAL_NED or BODY_FRD by child_frame_id;
  ``estimator_type`` VISION is our own mocap looped back and is ignored). PX4 streams
  LOCAL_POSITION_NED only while its xy position and velocity are valid
  (mavlink/streams/LOCAL_POSITION_NED.hpp), so an invalid estimate falls silent and goes
  stale here;
* GPS_GLOBAL_ORIGIN (latitude, longitude [degE7], altitude [mm AMSL]): the EKF origin, the
  geodetic anchor of the local frame; HOME_POSITION (same units) for the launch point.
  Both are asked for with MAV_CMD_REQUEST_MESSAGE until they arrive.

Frames: NED → ENU ((x, y, z) → (y, x, −z); R_ENU←FLU = P R_NED←FRD D), then the local ENU
frame at the EKF origin → the mission's world ENU frame at the shared mission origin
(:class:`~agent.flight.geodetic.LocalToWorld`, exact). Without a mission origin the world
frame is the EKF's local frame (one drone, or drones sharing one EKF origin by set-up).

Staleness as for mocap: each sample is stamped with the mission clock when it arrived
(``t`` [s mission]); the driver's stale-pose failsafe (``mocap_stale_s``) then levels and
lands when the estimate stops. Samples whose ``time_boot_ms`` does not advance (duplicates,
reordering) or that are not finite are dropped and counted; a jump back by more than 1 s is
an autopilot reboot (logged, accepted).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agent.flight.driver_types import FlightError, PoseSample
from agent.flight.frames import (
    ENU_TO_NED,
    FLU_TO_FRD,
    ned_to_enu,
    quat_from_euler,
    quat_from_matrix,
    quat_normalize,
    quat_to_matrix,
)
from agent.flight.geodetic import LocalToWorld, Origin, geodetic_to_enu
from agent.flight.link import VehicleLink
from agent.wire.mavlink import mavlink

_log = logging.getLogger(f"viscover.{__name__}")
Array = NDArray[np.float64]

_KINDS = ("LOCAL_POSITION_NED", "ATTITUDE", "ODOMETRY", "GPS_GLOBAL_ORIGIN", "HOME_POSITION")


def geodetic_of(lat_e7: int, lon_e7: int, alt_mm: int) -> Origin | None:
    """An :class:`Origin` from MAVLink integer units (degE7, degE7, mm); None if invalid."""
    try:
        return Origin(lat_e7 * 1e-7, lon_e7 * 1e-7, alt_mm * 1e-3)
    except ValueError:
        return None


class AutopilotPose:
    """Pose provider from the autopilot's estimate (see the module docstring).

    Args:
        link: the vehicle's link (started or not).
        mission_origin: the mission's shared geodetic origin (None: the EKF's local frame).
        on_pose: called after each accepted sample (e.g. ``driver.notify_pose``).
        attitude_stale_s: an ATTITUDE older than this [s wall] is not paired [s].
        max_origin_offset_m: the EKF origin must lie within this of the mission origin [m].
    """

    def __init__(self, link: VehicleLink, mission_origin: Origin | None = None,
                 on_pose: Callable[[], None] | None = None, attitude_stale_s: float = 0.5,
                 max_origin_offset_m: float = 5000.0) -> None:
        self.link = link
        self.clock = link.clock
        self.mission_origin = mission_origin
        self.on_pose = on_pose
        self.attitude_stale_s = attitude_stale_s
        self.max_origin_offset_m = max_origin_offset_m
        self.frame: LocalToWorld | None = None  #: EKF local ENU → world ENU
        self.home_world: Array | None = None  #: the home position [m; world ENU]
        self.received = 0
        self.dropped = 0
        self._home: Origin | None = None
        self._lock = threading.Lock()
        self._latest: PoseSample | None = None
        self._att: tuple[float, Array] | None = None  # (rx wall [s], q R_NED←FRD)
        self._last_boot_ms = -1
        self._last_ask = -math.inf
        self._unsubs = [link.subscribe(_KINDS, self._on_message),
                        link.add_ticker(self._ask_origin)]

    def close(self) -> None:
        """Stop listening."""
        for u in self._unsubs:
            u()

    def __call__(self) -> PoseSample | None:
        """The latest pose [m, m/s; world ENU; q R_ENU←FLU], or None before the first."""
        with self._lock:
            return self._latest

    @property
    def ready(self) -> bool:
        """Whether poses can be placed in the world frame (the EKF origin is known)."""
        return self.frame is not None

    def wait_ready(self, timeout_s: float = 5.0) -> None:
        """Wait for the EKF origin (with a mission origin) and the first pose; FlightError,
        one line, if not."""
        self._ask_origin(force=True)
        if self.mission_origin is not None:
            if not self.link.wait(lambda: self.frame is not None, timeout_s):
                raise FlightError(f"no GPS_GLOBAL_ORIGIN from the autopilot within "
                                  f"{timeout_s:g} s: has its EKF an origin (GNSS fix, or "
                                  "SET_GPS_GLOBAL_ORIGIN)?")
            frame = self.frame
            if frame is not None and frame.distance_m > self.max_origin_offset_m:
                raise FlightError(f"the autopilot's EKF origin is {frame.distance_m:.0f} m "
                                  f"from the mission origin (limit {self.max_origin_offset_m:g}"
                                  " m): wrong site or wrong mission origin?")
        if not self.link.wait(lambda: self() is not None, timeout_s):
            raise FlightError(f"no position estimate from the autopilot within {timeout_s:g} s")

    def _ask_origin(self, force: bool = False) -> None:
        """Ask for GPS_GLOBAL_ORIGIN / HOME_POSITION once a second until both came."""
        now = time.monotonic()
        if not force and (now - self._last_ask < self.clock.wall(1.0)):
            return
        self._last_ask = now
        if self.frame is None:
            self.link.send_command(mavlink.MAV_CMD_REQUEST_MESSAGE,
                                   float(mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN))
        if self._home is None:
            self.link.send_command(mavlink.MAV_CMD_REQUEST_MESSAGE,
                                   float(mavlink.MAVLINK_MSG_ID_HOME_POSITION))

    # -- inputs -------------------------------------------------------------------------------
    def _on_message(self, msg: Any) -> None:
        if msg.get_srcComponent() != self.link.cfg.target_component:
            return  # only the autopilot's own estimate
        kind = msg.get_type()
        if kind == "ATTITUDE":
            rpy = (float(msg.roll), float(msg.pitch), float(msg.yaw))
            if all(math.isfinite(a) for a in rpy):
                self._att = (time.monotonic(), quat_from_euler(*rpy))
            else:
                self.dropped += 1
        elif kind == "LOCAL_POSITION_NED":
            self._on_local(msg)
        elif kind == "ODOMETRY":
            self._on_odometry(msg)
        elif kind == "GPS_GLOBAL_ORIGIN":
            self._on_origin(geodetic_of(int(msg.latitude), int(msg.longitude), int(msg.altitude)))
        elif kind == "HOME_POSITION":
            self._home = geodetic_of(int(msg.latitude), int(msg.longitude), int(msg.altitude))
            self._place_home()

    def _on_origin(self, origin: Origin | None) -> None:
        if origin is None:
            self.dropped += 1
            return
        if self.frame is not None and self.frame.local == origin:
            return
        if self.frame is not None:
            _log.warning("the autopilot's EKF origin moved to %.7f, %.7f, %.2f m",
                         origin.lat, origin.lon, origin.alt)
        self.frame = LocalToWorld.between(origin, self.mission_origin)
        self._place_home()

    def _place_home(self) -> None:
        h, fr = self._home, self.frame
        if h is not None and fr is not None:
            self.home_world = np.asarray(geodetic_to_enu(h.lat, h.lon, h.alt, fr.world),
                                         dtype=np.float64)

    def _fresh_boot_time(self, boot_ms: int) -> bool:
        """Whether a sample stamped ``boot_ms`` is newer than the last (reboot accepted)."""
        last = self._last_boot_ms
        if last >= 0 and boot_ms < last - 1000:
            _log.warning("autopilot time went back %d ms: rebooted?", last - boot_ms)
        elif boot_ms <= last:
            return False
        self._last_boot_ms = boot_ms
        return True

    def _on_local(self, msg: Any) -> None:
        att = self._att
        if att is None or time.monotonic() - att[0] > self.clock.wall(self.attitude_stale_s):
            self.dropped += 1  # no attitude to pair with
            return
        p = np.array([msg.x, msg.y, msg.z], dtype=np.float64)
        v = np.array([msg.vx, msg.vy, msg.vz], dtype=np.float64)
        self._accept(int(msg.time_boot_ms), p, v, att[1])

    def _on_odometry(self, msg: Any) -> None:
        if int(msg.estimator_type) == mavlink.MAV_ESTIMATOR_TYPE_VISION \
                or int(msg.frame_id) != mavlink.MAV_FRAME_LOCAL_NED:
            self.dropped += 1  # our own vision looped back, or a frame without north
            return
        try:
            q = quat_normalize([float(a) for a in msg.q])
        except ValueError:
            self.dropped += 1
            return
        v = np.array([msg.vx, msg.vy, msg.vz], dtype=np.float64)
        if int(msg.child_frame_id) == mavlink.MAV_FRAME_BODY_FRD:
            v = quat_to_matrix(q) @ v
        elif int(msg.child_frame_id) != mavlink.MAV_FRAME_LOCAL_NED:
            self.dropped += 1
            return
        p = np.array([msg.x, msg.y, msg.z], dtype=np.float64)
        self._accept(int(int(msg.time_usec) // 1000), p, v, q)

    def _accept(self, boot_ms: int, p_ned: Array, v_ned: Array, q_ned_frd: Array) -> None:
        """One estimate (NED, R_NED←FRD) into the world frame, stamped now [s mission]."""
        fr = self.frame
        if fr is None and self.mission_origin is not None:
            self.dropped += 1  # not placeable before the EKF origin is known
            return
        if not (np.all(np.isfinite(p_ned)) and np.all(np.isfinite(v_ned))
                and np.all(np.isfinite(q_ned_frd))) or not self._fresh_boot_time(boot_ms):
            self.dropped += 1
            return
        r_local = ENU_TO_NED @ quat_to_matrix(q_ned_frd) @ FLU_TO_FRD  # R_ENU←FLU
        p, v = ned_to_enu(p_ned), ned_to_enu(v_ned)
        if fr is not None:
            p, v, r_local = fr.point(p), fr.vector(v), fr.rotation @ r_local
        sample = PoseSample(self.clock.now(), p, v, quat_from_matrix(r_local), time.monotonic())
        with self._lock:
            self._latest = sample
            self.received += 1
        if self.on_pose is not None:
            self.on_pose()
