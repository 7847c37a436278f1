"""The set-point streamer: poses in, SET_ATTITUDE_TARGET out, with the stale-pose failsafe,
the set-point guard and the space guard; poses forwarded to the autopilot's EKF.

* SET_ATTITUDE_TARGET at ``rate_hz`` (50 Hz default): q = R_NED←FRD (unit, checked), thrust
  0..1; type_mask 7 (attitude + thrust) or 3 with the body yaw rate as feed-forward
  (``yaw_rate_ff``; PX4 uses it, ArduCopter takes body rates all-or-none, so keep 7 there).
  Pose-driven: a set-point goes out as soon as a new pose arrives and at least
  ``(1 − slack)`` of a period has passed, or at the period plus ``slack`` without a new pose.
* Mocap is forwarded as VISION_POSITION_ESTIMATE or ODOMETRY (``forward``, at most
  ``forward_hz``; NED/FRD; covariances unknown: NaN first, MAVLink's convention). A pose
  that comes from the autopilot itself is never forwarded (``forward = "none"``).
* Stale pose (older than ``mocap_stale_s``, judged by :class:`~agent.flight.monitor.
  MocapAge` on the ground station's stamps, or on the driver's clock for other providers) →
  level attitude at the controller's current hover thrust (``failsafe_hold``); still stale
  after ``failsafe_hold_s`` → the autopilot's LAND. One line per failsafe and per recovery.
* A set-point with a NaN/inf or a non-unit quaternion is never sent: it is replaced by the
  level hover set-point and counted (``stats.blocked``).
* Space guard: the controller's position target never leaves the space [lo + margin,
  hi − margin] [m; world ENU] (the controller's own, or a narrower one given with
  :meth:`SetpointStreamer.set_space`, e.g. the uploaded fence): a target outside is clamped
  before the controller runs, counted (``stats.clamped``) and logged once per target.
* Fault injection (``faults``): set-points of kind ``setpoint`` are dropped as it decides.

Times are simulation seconds of the mission clock, pacing on the local monotonic clock at
the clock's scale.
"""

from __future__ import annotations

import logging
import math
import threading
import time

import numpy as np
from numpy.typing import ArrayLike, NDArray

from agent.flight.attitude import AttitudeCommand, level_attitude
from agent.flight.controllers import FlightController, FlightState, clip_to_space
from agent.flight.driver_types import DriverStats, PoseProvider, PoseSample
from agent.flight.frames import (
    enu_to_ned,
    euler_from_quat,
    quat_enu_flu_to_ned_frd,
    quat_is_unit,
    quat_to_matrix,
    yaw_enu_to_ned,
    yaw_from_quat,
)
from agent.flight.hover import AccelFromVelocity
from agent.flight.link import VehicleLink
from agent.flight.monitor import MocapAge
from agent.flight.supervisor import Supervisor
from agent.net.faults import FaultInjector
from agent.wire.mavlink import mavlink

_log = logging.getLogger(f"viscover.{__name__}")
Array = NDArray[np.float64]
_UNKNOWN_COV = [math.nan] + [0.0] * 20  # MAVLink: NaN in the first element = unknown


class SetpointStreamer:
    """Streams ``controller``'s set-points for the pose from ``pose`` (see the module
    docstring). ``notify_pose()`` wakes the stream when a pose arrives."""

    def __init__(self, link: VehicleLink, supervisor: Supervisor, pose: PoseProvider,
                 controller: FlightController, faults: FaultInjector | None = None) -> None:
        self.link = link
        self.sup = supervisor
        self.cfg = link.cfg
        self.clock = link.clock
        self.pose = pose
        self.controller = controller
        self.faults = faults
        self.stats = DriverStats()
        provided = getattr(pose, "mocap_age", None)
        self._own_age = not isinstance(provided, MocapAge)  # then fed from self.clock
        self.mocap_age: MocapAge = provided if isinstance(provided, MocapAge) else MocapAge()
        self.source_name = "mocap"  #: what the poses are, in the failsafe's log lines
        self.failsafe_reason = ""  #: why the last pose failsafe started (one line)
        self.failsafe_s = 0.0  #: how long the last pose failsafe lasted [s sim]
        self._failsafe_since: float | None = None
        self._accel = AccelFromVelocity()
        self._z_ground = math.inf
        self._cond = threading.Condition()
        self._pose_seq = 0
        self._last_fwd_t = -math.inf
        self._last_pose_t = -math.inf
        self._last_yaw_ned = 0.0
        lo, hi = controller.cfg.lo, controller.cfg.hi
        self._lo = np.asarray(lo, dtype=np.float64).copy()
        self._hi = np.asarray(hi, dtype=np.float64).copy()
        self._clamped_at: tuple[float, float, float] | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- lifecycle ------------------------------------------------------------------------
    def start(self) -> None:
        """Start the stream thread (set-points go out while ``supervisor.streaming``)."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._loop, name="mav-stream", daemon=True)
            self._thread.start()

    def close(self) -> None:
        """Stop and join the stream thread."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(5.0)
        self._thread = None

    def use_pose(self, provider: PoseProvider, name: str = "mocap") -> None:
        """Fly on another pose provider (called ``name`` in the log), its age judged as at
        construction: on its own ``mocap_age`` if it has one, else on the driver's clock (a
        pose stamped on arrival, such as the autopilot's own estimate)."""
        self.source_name = name
        provided = getattr(provider, "mocap_age", None)
        self._own_age = not isinstance(provided, MocapAge)
        self.mocap_age = provided if isinstance(provided, MocapAge) else MocapAge()
        self.pose = provider

    def notify_pose(self) -> None:
        """A new pose is available: wake the stream (call from the pose's receive thread)."""
        with self._cond:
            self._pose_seq += 1
            self._cond.notify_all()

    def prepare(self) -> None:
        """Before engaging: hold where it is, note the ground height, restart the
        acceleration estimate."""
        self.controller.set_hold()
        pose = self.pose()
        self._z_ground = float(pose.p[2]) if pose is not None else math.inf
        self._accel.reset()

    def set_space(self, lo: ArrayLike, hi: ArrayLike) -> None:
        """Fly within [lo, hi] [m; world ENU] (walls shrunk by the controller's margin): the
        guard's bounds and the controller's, e.g. the fence's inclusion box."""
        self._lo = np.asarray(lo, dtype=np.float64).copy()
        self._hi = np.asarray(hi, dtype=np.float64).copy()
        self.controller.cfg.lo, self.controller.cfg.hi = self._lo.copy(), self._hi.copy()

    # -- loop -------------------------------------------------------------------------------
    def _loop(self) -> None:
        """Pose-driven set-point stream with a deadline; the supervisor's watch each turn."""
        last_send = -math.inf
        seen = 0
        while not self._stop.is_set() and not self.link.closed:
            now = time.monotonic()
            period = self.clock.wall(1.0 / self.cfg.rate_hz)
            try:
                self.sup.watch()
            except Exception:
                _log.exception("vehicle monitor failed")
            due_pose = last_send + period * (1.0 - self.cfg.slack)
            due_late = last_send + period * (1.0 + self.cfg.slack)
            with self._cond:
                fresh = self._pose_seq != seen
                if not (fresh and now >= due_pose) and now < due_late:
                    # Early pose or none yet: sleep until the next pose or the deadline.
                    self._cond.wait(min(max(due_late - now, 1e-4), 0.1))
                    continue
                seen = self._pose_seq
            last_send = time.monotonic()
            try:
                self.step()
            except Exception:
                _log.exception("stream step failed")

    def step(self) -> None:
        """One stream period: read the pose, run the controller / failsafe, send."""
        pose = self.pose()
        now = self.clock.now()
        if self._own_age:
            self.mocap_age.heard(now)
        age = self.mocap_age.age(None if pose is None else pose.t)
        fresh = pose is not None and age <= self.cfg.mocap_stale_s
        if pose is not None and pose.t > self._last_pose_t:
            self._last_pose_t = pose.t
            self._forward(pose)
        if not self.sup.streaming:
            return
        if fresh and pose is not None:
            self._fly(pose, now)
            return
        self._failsafe(pose is None, age, now)

    def _fly(self, pose: PoseSample, now: float) -> None:
        if self._failsafe_since is not None:
            self.failsafe_s = max(0.0, now - self._failsafe_since)
            self._failsafe_since = None
            self.sup.note(logging.WARNING, "%s back after %.2f s: resuming", self.source_name,
                          self.failsafe_s)
            self.sup.phase = "flying"
            self.controller.set_hold()
        self._guard_space()
        yaw = yaw_from_quat(pose.q)
        a = self._accel.update(pose.t, pose.vel)
        armed = self.link.vehicle.armed
        airborne = armed and float(pose.p[2]) > self._z_ground + 0.1
        acc = np.asarray(a, dtype=np.float64) if a is not None and airborne else None
        sp = self.controller.update(FlightState(pose.p, pose.vel, yaw, pose.t, a=acc,
                                                on_ground=armed and not airborne))
        self._last_yaw_ned = yaw_enu_to_ned(yaw)
        self._send(sp.cmd, sp.yaw_rate_frd, pose.rx_wall)

    def _failsafe(self, no_pose: bool, age: float, now: float) -> None:
        """Stale or missing pose: level hover, then the autopilot's LAND."""
        if self._failsafe_since is None:
            self._failsafe_since = now
            self.stats.failsafes += 1
            self.failsafe_reason = self._stale_reason(no_pose, age)
            self.sup.note(logging.WARNING, "%s lost (%s): level hover at hover thrust",
                          self.source_name, self.failsafe_reason)
            self.sup.phase = "failsafe_hold"
        if now - self._failsafe_since < self.cfg.failsafe_hold_s:
            self._send(level_attitude(self._last_yaw_ned, self.controller.model), 0.0, 0.0)
            return
        _log.warning("%s still stale after %.1f s: landing", self.source_name,
                     self.cfg.failsafe_hold_s)
        self.sup.streaming = False
        if self.sup.may_command():
            self.sup.land_async()

    def _stale_reason(self, no_pose: bool, age: float) -> str:
        """Why the pose is not fresh, in a few words (ages in s sim, silence in s wall)."""
        if no_pose:
            return "no pose yet"
        if math.isinf(age):
            return f"ground station silent for {self.mocap_age.silent_for():.2f} s"
        return f"newest pose {age:.3f} s old, limit {self.cfg.mocap_stale_s:.3f} s"

    def _guard_space(self) -> None:
        """Clamp the controller's position target into the space (count, log once each)."""
        ctl = self.controller
        target = ctl.p_hold
        if ctl.mode != "hold" or target is None:
            return
        margin = ctl.cfg.margin
        inside = clip_to_space(target, self._lo, self._hi, margin)
        if np.array_equal(inside, target) or not np.all(np.isfinite(inside)):
            return
        self.stats.clamped += 1
        key = (float(target[0]), float(target[1]), float(target[2]))
        if key != self._clamped_at:
            _log.warning("position target (%.2f, %.2f, %.2f) m is outside the space: clamped "
                         "to (%.2f, %.2f, %.2f) m", *key, *(float(x) for x in inside))
        ctl.p_hold = inside
        self._clamped_at = (float(inside[0]), float(inside[1]), float(inside[2]))

    # -- send -------------------------------------------------------------------------------
    def _send(self, cmd: AttitudeCommand, yaw_rate_frd: float, rx_wall: float) -> None:
        """SET_ATTITUDE_TARGET after the guard: never a NaN/inf, never a non-unit q."""
        q, thrust = np.asarray(cmd.q, dtype=np.float64), float(cmd.thrust)
        ok = (quat_is_unit(q) and math.isfinite(thrust) and 0.0 <= thrust <= 1.0
              and math.isfinite(yaw_rate_frd))
        if not ok:
            self.stats.blocked += 1
            _log.error("blocked a non-finite or invalid set-point (q=%s thrust=%s)", q, thrust)
            fallback = level_attitude(self._last_yaw_ned, self.controller.model)
            q, thrust, yaw_rate_frd = fallback.q, fallback.thrust, 0.0
        mask = 3 if self.cfg.yaw_rate_ff else 7
        if self.faults is not None and self.faults.decide("setpoint", None, "out").dropped:
            self.stats.dropped += 1  # fault injection: this set-point is lost on the link
            return
        link, qq, rate = self.link, [float(a) for a in q], float(yaw_rate_frd)
        link.send(lambda mav: mav.set_attitude_target_send(
            link.ms(), link.target_system, self.cfg.target_component, mask, qq, 0.0, 0.0,
            rate, thrust))
        t = time.monotonic()
        self.stats.sent += 1
        self.stats.send_wall.append(t)
        if rx_wall > 0:
            self.stats.latency.append(t - rx_wall)

    def _forward(self, pose: PoseSample) -> None:
        """Mocap to the flight controller (VISION_POSITION_ESTIMATE or ODOMETRY, NED/FRD)."""
        if self.cfg.forward == "none" or pose.t - self._last_fwd_t < 1.0 / self.cfg.forward_hz:
            return
        p, q = enu_to_ned(pose.p), quat_enu_flu_to_ned_frd(pose.q)
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(pose.vel))):
            return
        self._last_fwd_t = pose.t
        usec = int(max(pose.t, 0.0) * 1e6)
        if self.cfg.forward == "vision":
            roll, pitch, yaw = euler_from_quat(q)
            self.link.send(lambda mav: mav.vision_position_estimate_send(
                usec, float(p[0]), float(p[1]), float(p[2]), roll, pitch, yaw, _UNKNOWN_COV))
        else:
            v_body = quat_to_matrix(q).T @ enu_to_ned(pose.vel)
            self.link.send(lambda mav: mav.odometry_send(
                usec, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_FRD,
                float(p[0]), float(p[1]), float(p[2]), [float(a) for a in q],
                float(v_body[0]), float(v_body[1]), float(v_body[2]),
                0.0, 0.0, 0.0, _UNKNOWN_COV, _UNKNOWN_COV))  # rates not measured: 0
        self.stats.forwarded += 1
