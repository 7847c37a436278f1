"""The simulated gimbal (protocol v2): a pitch/yaw device with limits and a slew rate, and the
autopilot's gimbal manager in front of it, as each autopilot runs it.

Physics: the device turns each axis towards its target at most ``VehicleParams.gimbal_rate``
[deg/s] (no MAVLink message carries a maximum rate: GIMBAL_MANAGER_INFORMATION and
GIMBAL_DEVICE_INFORMATION give the angle limits only). Pitch is held in the earth frame
(stabilised, roll 0), yaw relative to the vehicle unless yaw lock (earth frame) is asked.

* ArduPilot (libraries/AP_Mount/AP_Mount.cpp, AP_Mount_Backend.cpp), present when MNT1_TYPE
  ≠ 0, manager and device on the autopilot component (device id 1 = instance + 1).
  MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW (param1 pitch, param2 yaw [deg], param3/4 rates
  [deg/s], param5 GIMBAL_MANAGER_FLAGS, param7 device id: 0 primary, 1 first): FAILED
  without a mount or for another device id; RETRACT / NEUTRAL flags set that mode; pitch and
  yaw both numbers: angle target clamped to MNT1_PITCH_MIN/MAX and (body-frame yaw)
  MNT1_YAW_MIN/MAX [deg], ACCEPTED; else both rates numbers: rate target, ACCEPTED; else
  FAILED. GIMBAL_MANAGER_SET_PITCHYAW (rad, rad/s) likewise, ignored when angles and rates
  are all given. MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE: param1/2 outside −3..255 FAILED; −1
  unchanged, −2 the sender takes primary control, −3 the sender releases it.
  GIMBAL_MANAGER_INFORMATION (limits [rad], capability flags by the axes with min < max),
  GIMBAL_MANAGER_STATUS (ROLL_LOCK | PITCH_LOCK, YAW_LOCK with yaw lock; primary control),
  GIMBAL_DEVICE_ATTITUDE_STATUS (target 0/0, flags ROLL_LOCK | PITCH_LOCK (+ RETRACT /
  NEUTRAL, + YAW_LOCK with yaw lock), q of (roll 0, pitch earth frame, yaw body frame),
  angular velocity NaN as a servo mount has none, delta_yaw NaN).
* PX4 (src/modules/gimbal/input_mavlink.cpp, output_rc.cpp, mavlink streams
  GIMBAL_MANAGER_INFORMATION.hpp, GIMBAL_DEVICE_ATTITUDE_STATUS.hpp), present with
  MNT_MODE_IN = 4 (gimbal protocol v2). MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW is ACCEPTED only
  from the primary control (none at start: DENIED) set by MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE
  (0..255 explicit ids, −1 unchanged, −2 the autopilot itself, −3 release if the sender has
  it; always ACCEPTED). Angles are clamped at the output to ±MNT_RANGE_PITCH/2 (−
  MNT_OFF_PITCH), ±MNT_RANGE_YAW/2 [deg]. The device attitude is sent as the spoofed MAVLink
  gimbal (component MAV_COMP_ID_GIMBAL, gimbal_device_id 0) with flags NEUTRAL | ROLL_LOCK |
  PITCH_LOCK | YAW_LOCK as output_rc sets them; GIMBAL_MANAGER_INFORMATION / _STATUS name
  that device by its component id (current PX4 copies the id from its gimbal module; an
  older stream sent 0), which is how MAVSDK pairs device and manager.
"""

from __future__ import annotations

import math
from typing import Any

from agent.flight.frames import quat_from_euler, wrap_pi
from agent.wire.mavlink import mavlink as mav
from groundstation.vehicle.inbound import as_int

M = mav
NAN = math.nan
F = M  # GIMBAL_* flag names live on the dialect module


#: PX4's device flags (output_rc: NEUTRAL | ROLL_LOCK | PITCH_LOCK | YAW_LOCK, always).
PX4_DEVICE_FLAGS = int(F.GIMBAL_DEVICE_FLAGS_NEUTRAL | F.GIMBAL_DEVICE_FLAGS_ROLL_LOCK
                       | F.GIMBAL_DEVICE_FLAGS_PITCH_LOCK | F.GIMBAL_DEVICE_FLAGS_YAW_LOCK)
Limits = tuple[float, float, float, float, float, float]


def ardupilot_limits(pt: Any) -> Limits:
    """MNT1_{ROLL,PITCH,YAW}_{MIN,MAX} [deg] as (min, max) per axis [rad]."""
    return tuple(math.radians(float(pt[f"MNT1_{a}_{m}"]))  # type: ignore[return-value]
                 for a in ("ROLL", "PITCH", "YAW") for m in ("MIN", "MAX"))


def px4_limits(pt: Any) -> Limits:
    """±MNT_RANGE_<axis>/2 less MNT_OFF_<axis> [deg] as (min, max) per axis [rad]."""
    def span(axis: str) -> tuple[float, float]:
        half = float(pt[f"MNT_RANGE_{axis}"]) / 2.0
        off = float(pt[f"MNT_OFF_{axis}"])
        return math.radians(-half - off), math.radians(half - off)
    return (*span("ROLL"), *span("PITCH"), *span("YAW"))


class Gimbal:
    """One vehicle's gimbal device and manager (module docstring)."""

    def __init__(self, ap: Any) -> None:
        self.ap = ap
        self.pitch = 0.0  #: actual pitch [rad; earth frame]
        self.yaw = 0.0  #: actual yaw [rad; body frame]
        self.target = (0.0, 0.0)  #: angle target (pitch, yaw) [rad]
        self.rate: tuple[float, float] | None = None  #: rate target [rad/s] (None: angles)
        self.yaw_lock = False
        self.mode = "angle"  #: angle | rate | neutral | retract
        self.control = (0, 0)  #: primary control (system, component)
        self._t = 0.0

    # -- configuration ------------------------------------------------------------------
    @property
    def present(self) -> bool:
        """A gimbal is configured (MNT1_TYPE ≠ 0; PX4 MNT_MODE_IN = 4)."""
        return bool(self.ap.flavour.gimbal_present(self.ap.params_table))

    @property
    def device_id(self) -> int:
        """gimbal_device_id in the manager's messages: ArduPilot instance + 1; PX4 the
        (spoofed) MAVLink gimbal's component id."""
        return int(self.ap.flavour.gimbal_device_id)

    @property
    def component(self) -> int:
        """Component that sends GIMBAL_DEVICE_ATTITUDE_STATUS."""
        return int(self.ap.flavour.gimbal_component)

    def limits(self) -> tuple[float, float, float, float, float, float]:
        """(roll_min, roll_max, pitch_min, pitch_max, yaw_min, yaw_max) [rad]."""
        return self.ap.flavour.gimbal_limits(self.ap.params_table)  # type: ignore[no-any-return]

    # -- commands -----------------------------------------------------------------------
    def command_pitchyaw(self, p: list[float], src: tuple[int, int]) -> int:
        """MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW; p holds param1..param7."""
        fl = self.ap.flavour
        if not self.present:
            return int(fl.gimbal_absent_result)
        flags = as_int(p[4], (0, 0xFFFFFFFF)) if math.isfinite(p[4]) else 0
        if flags is None:
            return int(M.MAV_RESULT_DENIED)
        refused = fl.gimbal_command_refusal(self, p, src)
        if refused is not None:
            return int(refused)
        angles = (math.radians(p[0]), math.radians(p[1]))
        rates = (math.radians(p[2]), math.radians(p[3]))
        ok = self._set(flags, angles, rates)
        return int(M.MAV_RESULT_ACCEPTED if ok else fl.gimbal_unset_result)

    def on_set_pitchyaw(self, m: Any) -> None:
        """GIMBAL_MANAGER_SET_PITCHYAW (rad, rad/s); ignored as each autopilot ignores it."""
        if not self.present:
            return
        src = (m.get_srcSystem(), m.get_srcComponent())
        angles, rates = (float(m.pitch), float(m.yaw)), (float(m.pitch_rate), float(m.yaw_rate))
        if self.ap.flavour.gimbal_message_taken(self, m, src, angles, rates):
            self._set(int(m.flags), angles, rates)

    def command_configure(self, p: list[float], src: tuple[int, int]) -> int:
        """MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE (module docstring)."""
        if not self.present:
            return int(self.ap.flavour.gimbal_absent_result)
        sys_id, comp_id = as_int(p[0], (-3, 255)), as_int(p[1], (-3, 255))
        if sys_id is None or comp_id is None:
            return int(M.MAV_RESULT_DENIED if not all(map(math.isfinite, p[:2]))
                       else M.MAV_RESULT_FAILED)
        cur = self.control
        me = (self.ap.sysid, 1)
        new = list(cur)
        for k, v in enumerate((sys_id, comp_id)):
            if v >= 0:
                new[k] = v
            elif v == -2:
                new[k] = me[k] if self.ap.flavour.gimbal_control_to_autopilot else src[k]
            elif v == -3 and cur[k] == src[k]:
                new[k] = 0
        self.control = (new[0], new[1])
        return int(M.MAV_RESULT_ACCEPTED)

    def _set(self, flags: int, angles: tuple[float, float], rates: tuple[float, float]) -> bool:
        if flags & F.GIMBAL_MANAGER_FLAGS_RETRACT:
            self.mode = "retract"
            return True
        if flags & F.GIMBAL_MANAGER_FLAGS_NEUTRAL:
            self.mode = "neutral"
            return True
        lock = bool(flags & F.GIMBAL_MANAGER_FLAGS_YAW_LOCK)
        lim = self.limits()
        if not any(math.isnan(a) for a in angles):
            pitch = min(max(angles[0], lim[2]), lim[3])
            yaw = angles[1] if lock else min(max(wrap_pi(angles[1]), lim[4]), lim[5])
            self.target, self.rate, self.yaw_lock, self.mode = (pitch, yaw), None, lock, "angle"
            return True
        if not any(math.isnan(r) for r in rates):
            self.rate, self.yaw_lock, self.mode = (rates[0], rates[1]), lock, "rate"
            self.target = (self.pitch, self.yaw)
            return True
        return False

    # -- physics ------------------------------------------------------------------------
    def step(self, t: float, vehicle_yaw: float) -> None:
        """Move the device towards its target until simulation time t [s]."""
        dt = max(t - self._t, 0.0)
        self._t = t
        if not self.present or dt == 0.0:
            return
        lim = self.limits()
        if self.mode in ("neutral", "retract"):
            goal = (0.0, 0.0)
        else:
            if self.mode == "rate" and self.rate is not None:
                pitch = min(max(self.target[0] + self.rate[0] * dt, lim[2]), lim[3])
                self.target = (pitch, self.target[1] + self.rate[1] * dt)
            yaw_bf = wrap_pi(self.target[1] - vehicle_yaw) if self.yaw_lock else self.target[1]
            goal = (min(max(self.target[0], lim[2]), lim[3]),
                    min(max(yaw_bf, lim[4]), lim[5]))
        step = math.radians(float(self.ap.params.gimbal_rate)) * dt
        self.pitch += min(max(goal[0] - self.pitch, -step), step)
        self.yaw += min(max(wrap_pi(goal[1] - self.yaw), -step), step)

    def camera_q(self, att: tuple[float, float, float]) -> list[float]:
        """Camera attitude (w, x, y, z) [NED → camera FRD, x along the optical axis] of a
        vehicle with attitude ``att`` (roll, pitch, yaw [rad]); fixed to the body without a
        gimbal."""
        if not self.present:
            return [float(a) for a in quat_from_euler(*att)]
        return [float(a) for a in quat_from_euler(0.0, self.pitch, wrap_pi(att[2] + self.yaw))]

    # -- messages -----------------------------------------------------------------------
    def device_flags(self) -> int:
        """GIMBAL_DEVICE_ATTITUDE_STATUS.flags (module docstring; the flavour's)."""
        return int(self.ap.flavour.gimbal_device_flags(self))

    def mount_flags(self) -> int:
        """ArduPilot's: roll and pitch lock, plus retract, neutral or yaw lock by the mode."""
        flags = int(F.GIMBAL_DEVICE_FLAGS_ROLL_LOCK | F.GIMBAL_DEVICE_FLAGS_PITCH_LOCK)
        if self.mode == "retract":
            flags |= F.GIMBAL_DEVICE_FLAGS_RETRACT
        elif self.mode == "neutral":
            flags |= F.GIMBAL_DEVICE_FLAGS_NEUTRAL
        elif self.yaw_lock:
            flags |= F.GIMBAL_DEVICE_FLAGS_YAW_LOCK
        return flags

    def send_attitude(self, ms: int) -> None:
        """GIMBAL_DEVICE_ATTITUDE_STATUS from the device's component."""
        q = [float(a) for a in quat_from_euler(0.0, self.pitch, self.yaw)]
        self.ap.encoder(self.component).gimbal_device_attitude_status_send(
            0, 0, ms, self.device_flags(), q, NAN, NAN, NAN, 0, NAN, NAN,
            self.ap.flavour.gimbal_attitude_device_id)

    def cap_flags(self) -> int:
        """GIMBAL_MANAGER_CAP_FLAGS (ArduPilot's rule: an axis whose min < max)."""
        lim = self.limits()
        flags = int(F.GIMBAL_MANAGER_CAP_FLAGS_HAS_RETRACT | F.GIMBAL_MANAGER_CAP_FLAGS_HAS_NEUTRAL
                    | F.GIMBAL_MANAGER_CAP_FLAGS_HAS_RC_INPUTS
                    | F.GIMBAL_MANAGER_CAP_FLAGS_CAN_POINT_LOCATION_LOCAL
                    | F.GIMBAL_MANAGER_CAP_FLAGS_CAN_POINT_LOCATION_GLOBAL)
        for k, axis in enumerate(("ROLL", "PITCH", "YAW")):
            if lim[2 * k] < lim[2 * k + 1]:
                for what in ("AXIS", "FOLLOW", "LOCK"):
                    flags |= getattr(F, f"GIMBAL_MANAGER_CAP_FLAGS_HAS_{axis}_{what}")
        return flags

    def send_manager_information(self, ms: int) -> None:
        """GIMBAL_MANAGER_INFORMATION from the autopilot."""
        self.ap.mav.gimbal_manager_information_send(ms, self.cap_flags(), self.device_id,
                                                    *self.limits())

    def send_manager_status(self, ms: int) -> None:
        """GIMBAL_MANAGER_STATUS from the autopilot."""
        flags = F.GIMBAL_MANAGER_FLAGS_ROLL_LOCK | F.GIMBAL_MANAGER_FLAGS_PITCH_LOCK
        if self.yaw_lock:
            flags |= F.GIMBAL_MANAGER_FLAGS_YAW_LOCK
        self.ap.mav.gimbal_manager_status_send(ms, flags, self.device_id, *self.control, 0, 0)

    def send_device_information(self, ms: int) -> None:
        """GIMBAL_DEVICE_INFORMATION (limits [rad]; this simulator's vendor and model)."""
        dev = (F.GIMBAL_DEVICE_CAP_FLAGS_HAS_NEUTRAL | F.GIMBAL_DEVICE_CAP_FLAGS_HAS_RETRACT
               | F.GIMBAL_DEVICE_CAP_FLAGS_HAS_PITCH_AXIS | F.GIMBAL_DEVICE_CAP_FLAGS_HAS_PITCH_LOCK
               | F.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_AXIS | F.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_FOLLOW
               | F.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_LOCK)
        self.ap.mav.gimbal_device_information_send(
            ms, b"viscover", b"sim-gimbal-2axis", b"", 0x01000000, 0, 0x56495347 + self.ap.sysid,
            dev, 0, *self.limits(), self.device_id)
