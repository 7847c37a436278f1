"""The gimbal client (gimbal protocol v2): the camera tilt θ of eqs. 2.3-2.5 commanded on the
vehicle's gimbal and measured back, with its limits for the planner; a simulated tilt when
the vehicle has none.

* Discovery: MAV_CMD_REQUEST_MESSAGE for GIMBAL_MANAGER_INFORMATION (280) to the autopilot,
  the gimbal manager on both autopilots (ArduPilot AP_Mount_Backend::send_gimbal_manager_
  information: limits from MNTx_PITCH_MIN/MAX etc. in rad, gimbal_device_id = instance + 1;
  PX4 gimbal module). Its pitch_min/pitch_max [rad] bound θ. The protocol carries no rate
  limit: ``rate_max`` [rad/s] is the configured one (the gimbal's data sheet).
* Control: MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE (1001), param1/param2 = our system /
  component as primary control (PX4's gimbal accepts PITCHYAW only from its primary
  control, else DENIED; ArduPilot takes explicit ids as given), param7 = the device id.
* Command: MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW (1000): param1 pitch [deg] (positive up),
  param2 yaw [deg] = 0 in the vehicle frame (the camera looks along the heading; ArduPilot
  needs both angles finite), param3/4 rates NaN (angle control), param5 flags ROLL_LOCK |
  PITCH_LOCK (roll and pitch held to the horizon, yaw follows the vehicle), param7 device id.
  Sent at most every ``command_period_s`` and only when θ moved by ``deadband_rad``.
* Measurement: GIMBAL_DEVICE_ATTITUDE_STATUS q (w, x, y, z), its pitch (ZYX, up positive;
  the pitch does not depend on whether yaw is in the vehicle or earth frame), of the
  device ``gimbal_device_id`` (0 = the sender is the device). Fresh for ``stale_s``.

Without GIMBAL_MANAGER_INFORMATION within ``discover_timeout_s`` the tilt is simulated
(θ is whatever was commanded, limits ±(π/2 − 1e-3)) and the log says so. Angles in rad,
times in s of simulation time.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import Any

from agent.flight.driver_types import FlightError
from agent.flight.frames import euler_from_quat
from agent.flight.link import VehicleLink
from agent.wire.mavlink import mavlink

_log = logging.getLogger(f"viscover.{__name__}")
_MANAGER_INFO_ID = 280  # GIMBAL_MANAGER_INFORMATION
_FLAGS = mavlink.GIMBAL_MANAGER_FLAGS_ROLL_LOCK | mavlink.GIMBAL_MANAGER_FLAGS_PITCH_LOCK
_SIM_LIMIT = math.pi / 2 - 1e-3


@dataclass(frozen=True)
class GimbalConfig:
    """Discovery time-out [s], the rate limit [rad/s], how long a measurement is fresh [s],
    command pacing [s] and dead band [rad]."""

    discover_timeout_s: float = 2.0
    rate_max: float = math.radians(90.0)
    stale_s: float = 0.5
    command_period_s: float = 0.1
    deadband_rad: float = math.radians(0.2)


@dataclass(frozen=True)
class GimbalLimits:
    """What the planner must respect: tilt (pitch) limits [rad], yaw limits [rad], the rate
    limit [rad/s]; the device id and whether the tilt is ``simulated``."""

    pitch_min: float = -_SIM_LIMIT
    pitch_max: float = _SIM_LIMIT
    yaw_min: float = -math.pi
    yaw_max: float = math.pi
    rate_max: float = math.radians(90.0)
    device_id: int = 0
    simulated: bool = True

    def clamp(self, theta: float) -> float:
        """θ [rad] within [pitch_min, pitch_max]."""
        return min(max(theta, self.pitch_min), self.pitch_max)


class GimbalClient:
    """Commands and reads the camera tilt θ [rad] (see the module docstring)."""

    def __init__(self, link: VehicleLink, config: GimbalConfig | None = None) -> None:
        self.link = link
        self.cfg = config or GimbalConfig()
        self.limits = GimbalLimits(rate_max=self.cfg.rate_max)
        self.denied = 0  #: PITCHYAW commands the manager refused
        self.bad = 0  #: attitude reports that could not be read
        self._lock = threading.Lock()
        self._info: Any = None
        self._commanded = 0.0
        self._sent: tuple[float, float] | None = None  # (θ, monotonic) of the last command
        self._measured: tuple[float, float] | None = None  # (θ, monotonic)
        self._unsubs = [
            link.subscribe("GIMBAL_MANAGER_INFORMATION", self._on_info),
            link.subscribe("GIMBAL_DEVICE_ATTITUDE_STATUS", self._on_attitude),
            link.subscribe("COMMAND_ACK", self._on_ack)]

    def close(self) -> None:
        """Stop listening."""
        for u in self._unsubs:
            u()

    @property
    def present(self) -> bool:
        """Whether the vehicle has a gimbal (else the tilt is simulated)."""
        return not self.limits.simulated

    def _on_info(self, msg: Any) -> None:
        if msg.get_srcComponent() == self.link.cfg.target_component:
            self._info = msg

    def discover(self) -> GimbalLimits:
        """Ask for GIMBAL_MANAGER_INFORMATION; take control of the gimbal it names. Without
        an answer the tilt is simulated (said once in the log)."""
        link = self.link
        link.send_command(mavlink.MAV_CMD_REQUEST_MESSAGE, float(_MANAGER_INFO_ID))
        if not link.wait(lambda: self._info is not None, self.cfg.discover_timeout_s):
            _log.warning("no gimbal (no GIMBAL_MANAGER_INFORMATION within %g s): camera tilt "
                         "simulated", self.cfg.discover_timeout_s)
            return self.limits
        m = self._info
        vals = [float(m.pitch_min), float(m.pitch_max), float(m.yaw_min), float(m.yaw_max)]
        if not all(math.isfinite(v) for v in vals) or vals[0] > vals[1]:
            _log.warning("gimbal limits unreadable (%s): camera tilt simulated", vals)
            return self.limits
        self.limits = GimbalLimits(vals[0], vals[1], vals[2], vals[3], self.cfg.rate_max,
                                   int(m.gimbal_device_id), simulated=False)
        _log.info("gimbal %d: tilt %.1f..%.1f deg", self.limits.device_id,
                  math.degrees(vals[0]), math.degrees(vals[1]))
        self.take_control()
        return self.limits

    def take_control(self) -> bool:
        """MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE with us as primary control; True if ACCEPTED."""
        link = self.link
        try:
            res = link.command(mavlink.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE,
                               float(link.own_system), float(link.own_component), -1.0, -1.0,
                               0.0, 0.0, float(self.limits.device_id))
        except FlightError as e:  # the tilt is then unconfirmed
            _log.warning("gimbal: %s", e)
            return False
        accepted = bool(res == mavlink.MAV_RESULT_ACCEPTED)
        if not accepted:
            _log.warning("gimbal: control refused (MAV_RESULT %d)", res)
        return accepted

    # -- tilt -----------------------------------------------------------------------------------
    def set_tilt(self, theta: float) -> float:
        """Command tilt θ [rad] (clamped to the limits); returns the θ commanded."""
        if not math.isfinite(theta):
            return self._commanded
        th = self.limits.clamp(theta)
        self._commanded = th
        if self.limits.simulated:
            return th
        now = time.monotonic()
        last, period = self._sent, self.link.clock.wall(self.cfg.command_period_s)
        if last is not None and (abs(th - last[0]) < self.cfg.deadband_rad
                                 or now - last[1] < period):
            return th
        self._sent = (th, now)
        self.link.send_command(mavlink.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, math.degrees(th), 0.0,
                               math.nan, math.nan, float(_FLAGS), 0.0,
                               float(self.limits.device_id))
        return th

    def tilt(self) -> float:
        """The tilt θ [rad]: measured if a fresh GIMBAL_DEVICE_ATTITUDE_STATUS came, else the
        commanded (simulated) one."""
        m = self.measured()
        return self._commanded if m is None else m

    def measured(self) -> float | None:
        """The measured tilt [rad] if fresh (``stale_s``), else None."""
        with self._lock:
            m = self._measured
        if m is None or time.monotonic() - m[1] > self.link.clock.wall(self.cfg.stale_s):
            return None
        return m[0]

    def _on_attitude(self, msg: Any) -> None:
        dev = int(getattr(msg, "gimbal_device_id", 0))
        if dev not in (0, self.limits.device_id) and not self.limits.simulated:
            return  # another gimbal's
        try:
            _, pitch, _ = euler_from_quat([float(a) for a in msg.q])
        except ValueError:
            self.bad += 1
            return
        if not math.isfinite(pitch):
            self.bad += 1
            return
        with self._lock:
            self._measured = (pitch, time.monotonic())

    def _on_ack(self, msg: Any) -> None:
        if int(msg.command) != mavlink.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW \
                or not self.link.ack_is_ours(msg):
            return
        if int(msg.result) not in (mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_IN_PROGRESS):
            self.denied += 1
            if self.denied == 1:
                _log.warning("gimbal: tilt command refused (MAV_RESULT %d)", int(msg.result))
            self._sent = None  # send again next time
