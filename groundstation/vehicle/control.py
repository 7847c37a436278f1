"""The simulated autopilot's inner loops: what each mode commands the dynamics to do.

Per tick, :meth:`Controls.targets` turns the autopilot's mode, its last accepted set-point
and the vehicle's state (the simulated EKF sees the true state) into (roll, pitch, yaw [rad;
NED], normalised thrust) for :func:`groundstation.vehicle.dynamics.step`. The vertical loop
uses the autopilot's own hover-thrust parameter (MOT_THST_HOVER / MPC_THR_HOVER) as its
feed-forward, so a wrong value shows as an altitude error, as on a real vehicle. What differs
per autopilot (thrust reading, set-point timeout, landing and return speeds) is the flavour's
(:mod:`groundstation.vehicle.flavours`).
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from agent.flight.frames import wrap_pi

if TYPE_CHECKING:
    from collections.abc import Callable

    from groundstation.vehicle.dynamics import VehicleState
    from groundstation.vehicle.flavours.base import SimFlavour
    from groundstation.vehicle.params import ParamTable, VehicleParams

Array = NDArray[np.float64]
Targets = tuple[float, float, float, float]

#: ArduCopter's land detector: landed after this long on the ground [s]
#: (LAND_DETECTOR_TRIGGER_SEC, ArduCopter/land_detector.cpp).
AP_LAND_DETECT_S = 1.0
#: Position hold: position gain [1/s], velocity gain [1/s], limits [m/s], [m/s²].
KP_POS, KP_VEL, MAX_SPEED, MAX_ACCEL = 1.0, 2.0, 2.0, 3.0


@dataclass
class VehicleLog:
    """What the vehicle saw (for tests and reports): events (t, name), counters, last
    accepted set-point and the wall times of set-points and mocap."""

    events: list[tuple[float, str]] = field(default_factory=list)
    setpoints: int = 0
    rejected_quat: int = 0
    rejected_nonfinite: int = 0
    rejected_mask: int = 0
    rejected_mode: int = 0
    vision: int = 0
    odometry: int = 0
    heartbeats_rx: int = 0
    last_thrust: float = math.nan
    last_q: Array = field(default_factory=lambda: np.full(4, np.nan))
    last_type_mask: int = -1
    last_setpoint_wall: float = 0.0
    last_vision_wall: float = 0.0
    setpoint_times: deque[float] = field(default_factory=lambda: deque(maxlen=4096))

    def has(self, name: str) -> bool:
        """Whether event ``name`` happened."""
        return any(n == name for _, n in self.events)


class Controls:
    """Set-point state and the per-mode controllers of one autopilot (mixin of
    :class:`groundstation.vehicle.autopilot.Autopilot`)."""

    i: int
    flavour: SimFlavour
    armed: bool
    mode: int
    params: VehicleParams
    params_table: ParamTable
    log: VehicleLog
    truth: Callable[[], VehicleState]
    rng: np.random.Generator
    mission: Any  #: groundstation.vehicle.mission_exec.MissionExec (the devices make it)

    def __init__(self) -> None:
        # Last accepted set-point (NED/FRD) and its simulation time.
        self.sp_rpy = (0.0, 0.0, 0.0)
        self.sp_thrust = 0.0
        self.sp_yaw_rate: float | None = None
        self.sp_t = -math.inf
        self.sp_recent: deque[float] = deque(maxlen=16)
        self.sp_hold_alt = False  # guided angle controller (re)started: level, climb 0
        self.guided_angle = False  # ArduCopter GUIDED switched to its angle sub-mode
        self.failsafe = False
        st = self.truth()
        self.home: Array = st.p[self.i].copy()
        self.hold_p: Array = st.p[self.i].copy()
        self.hold_z = float(st.p[self.i, 2])
        self.hold_yaw = float(st.att[self.i, 2])
        self.rtl_landing = False
        self.landed = True
        self.ground_since: float | None = None

    # -- hooks of the autopilot ---------------------------------------------------------
    @property
    def kind(self) -> str:
        """Behaviour of the current mode (overridden by the autopilot)."""
        raise NotImplementedError

    def event(self, t: float, name: str) -> None:
        """Record an event (overridden by the autopilot)."""
        raise NotImplementedError

    def on_setpoint_timeout(self, t: float) -> None:
        """The set-point stream timed out (overridden by the autopilot)."""
        raise NotImplementedError

    def position_ok(self, t: float) -> bool:
        """The simulated EKF has a position (overridden by the autopilot)."""
        raise NotImplementedError

    def pose_source(self, t: float) -> str | None:
        """Where the EKF's position comes from (overridden by the autopilot's devices)."""
        raise NotImplementedError

    def takeoff_target(self) -> float:
        """A takeoff mode's altitude [m; NED] (overridden by the autopilot)."""
        raise NotImplementedError

    def on_takeoff_done(self, t: float) -> None:
        """The takeoff mode reached its altitude (overridden by the autopilot)."""
        raise NotImplementedError

    # -- state --------------------------------------------------------------------------
    def on_ground(self) -> bool:
        """The vehicle rests on the ground (z ≥ −1 mm NED, not climbing)."""
        st = self.truth()
        return bool(st.p[self.i, 2] >= -1e-3 and st.v[self.i, 2] >= -1e-3)

    def estimate(self) -> tuple[Array, Array, Array, Array]:
        """The EKF's view: p [m; NED], v [m/s; NED], attitude [rad], Euler rates [rad/s]: with
        a GNSS position the true state plus the GNSS error model
        (:mod:`groundstation.vehicle.ekf`), else plus the configured sensor noise (seeded)."""
        st, p = self.truth(), self.params
        pos, att = st.p[self.i].copy(), st.att[self.i].copy()
        vel = st.v[self.i].copy()
        gnss = getattr(self, "gnss", None)
        t = float(getattr(self, "t_now", 0.0))
        if gnss is not None and self.pose_source(t) == "gnss":
            pos, vel, att = gnss.estimate(t, pos, vel, att)
            return pos, vel, att, st.rates[self.i].copy()
        if p.sensor_noise_pos > 0:
            pos += self.rng.normal(0.0, p.sensor_noise_pos, 3)
        if p.sensor_noise_att > 0:
            att += self.rng.normal(0.0, p.sensor_noise_att, 3)
        return pos, vel, att, st.rates[self.i].copy()

    def home_ned(self) -> Array:
        """Home [m; NED]: where the vehicle was armed (its start before that)."""
        return self.home

    @property
    def position_controlled(self) -> bool:
        """The horizontal position controller runs (ArduCopter's ``NE_is_active``)."""
        k = self.kind
        return k in ("hold", "rtl", "auto") or (
            k == "guided" and self.mode in self.flavour.position_guided_modes
            and not self.guided_angle)

    @property
    def setpoint_timeout(self) -> float:
        """GUID_TIMEOUT (at least 0.1 s, ``ModeGuided::get_timeout_ms``) / COM_OF_LOSS_T [s]."""
        return float(self.flavour.setpoint_timeout(self.params_table))

    def fresh_setpoint(self, t: float) -> bool:
        """A set-point arrived within the set-point timeout before t [s]."""
        return bool(self.sp_recent) and t - self.sp_recent[-1] < self.setpoint_timeout

    # -- set-points and modes -----------------------------------------------------------
    def accept_setpoint(self, t: float, rpy: tuple[float, float, float], thrust: float,
                        yaw_rate: float | None) -> None:
        """Store an accepted attitude set-point (NED/FRD) received at t [s]."""
        self.sp_rpy = rpy
        self.sp_thrust = min(max(thrust, self.flavour.min_thrust), 1.0)
        self.sp_yaw_rate = yaw_rate
        self.sp_t = t
        self.sp_hold_alt = False
        self.guided_angle = True
        self.log.setpoints += 1
        self.log.last_setpoint_wall = time.monotonic()
        if self.failsafe:
            self.failsafe = False
            self.event(t, "setpoints_resumed")

    def _reinit_guided(self, t: float, why: str) -> None:
        """ArduCopter ``mode_guided.init(true)`` on a bad set-point: level, climb rate 0."""
        self.event(t, why)
        if not self.flavour.reinit_on_bad_setpoint:
            return
        self.sp_rpy = (0.0, 0.0, float(self.truth().att[self.i, 2]))
        self.sp_hold_alt, self.sp_t = True, t
        self.hold_z = float(self.truth().p[self.i, 2])

    def start_mode(self, t: float) -> None:
        """A mode was entered: its controller starts from the current state."""
        st = self.truth()
        self.hold_p = st.p[self.i].copy()
        self.hold_z = float(st.p[self.i, 2])
        self.hold_yaw = float(st.att[self.i, 2])
        self.sp_rpy = (0.0, 0.0, self.hold_yaw)
        self.sp_hold_alt = True
        self.guided_angle = False
        self.rtl_landing = False

    # -- controllers --------------------------------------------------------------------
    def targets(self, t: float) -> Targets:
        """(roll, pitch, yaw [rad; NED], thrust 0..1) for this tick."""
        st = self.truth()
        i = self.i
        z, vz, yaw_now = float(st.p[i, 2]), float(st.v[i, 2]), float(st.att[i, 2])
        self._update_landed(t)
        if not self.armed:
            return 0.0, 0.0, yaw_now, 0.0
        kind = self.kind
        if kind == "guided" and self.position_controlled:
            kind = "hold"  # ArduCopter GUIDED before any attitude set-point
        if kind == "auto":  # the stored mission (groundstation.vehicle.mission_fly)
            out = self.mission.fly.step(t)
            return self.targets(t) if out is None else out  # None: it left AUTO
        if kind == "rtl":
            return self._rtl(t)
        if kind == "land":
            return self._land(t, vz)
        if kind == "hold":
            return self._hold(self.hold_p, self.hold_yaw)
        if kind == "takeoff":  # PX4 AUTO.TAKEOFF: climb over hold_p, then AUTO.LOITER
            z_t = self.takeoff_target()
            if abs(z - z_t) < 0.05 and abs(vz) < 0.1:
                self.on_takeoff_done(t)
            return self._hold(np.array([self.hold_p[0], self.hold_p[1], z_t]), self.hold_yaw)
        if kind == "alt":
            return 0.0, 0.0, self.hold_yaw, self._climb_thrust(0.0, z - self.hold_z)
        if kind != "guided":
            return 0.0, 0.0, yaw_now, 0.0  # manual modes without RC: idle
        if t - self.sp_t > self.setpoint_timeout and not self.failsafe:
            self.failsafe = True
            self.hold_z, self.hold_yaw = z, yaw_now
            self.on_setpoint_timeout(t)
            if self.kind != "guided":
                return self.targets(t)
        if self.failsafe or self.sp_hold_alt:
            if self.landed:
                return 0.0, 0.0, yaw_now, 0.0
            yaw = self.hold_yaw if self.failsafe else self.sp_rpy[2]
            return 0.0, 0.0, yaw, self._climb_thrust(0.0, z - self.hold_z)
        roll, pitch, yaw = self.sp_rpy
        if self.sp_yaw_rate is not None and self.flavour.yaw_rate_feedforward:
            yaw = wrap_pi(yaw + self.sp_yaw_rate * (t - self.sp_t))
        thrust = self.sp_thrust
        if self.flavour.thrust_is_climb_rate(self.params_table):
            thrust = self._climb_thrust(self._climb_rate_of(thrust), 0.0)
            positive = thrust > 0 and self.sp_thrust > 0.5
        else:
            positive = thrust > 0
        if self.landed and not positive and self.flavour.waits_on_ground:
            return 0.0, 0.0, yaw_now, 0.0  # ArduCopter waits on the ground
        return roll, pitch, yaw, min(max(thrust, 0.0), 1.0)

    def _climb_rate_of(self, thrust: float) -> float:
        """ArduCopter's thrust → climb rate [m/s up]: 0.5 holds, WPNAV_SPEED_UP / _DN."""
        thrust = min(max(thrust, 0.0), 1.0)
        if thrust >= 0.5:
            return (thrust - 0.5) * 2.0 * self.params_table["WPNAV_SPEED_UP"] / 100.0
        return (thrust - 0.5) * 2.0 * self.params_table["WPNAV_SPEED_DN"] / 100.0

    def _hover(self) -> float:
        return float(self.params_table[self.flavour.autopilot.hover_param])

    def _climb_thrust(self, climb_up: float, z_err: float) -> float:
        """Vertical loop: thrust for a climb rate [m/s up] plus altitude hold (z error [m;
        NED], positive below the target), on the autopilot's hover-thrust belief."""
        vz = float(self.truth().v[self.i, 2])
        a_up = 2.0 * (climb_up + vz) + 1.5 * z_err  # NED: −vz is up
        return min(max(self._hover() * (1.0 + a_up / self.params.g), 0.0), 1.0)

    def _hold(self, p_t: Array, yaw_t: float, climb: float | None = None) -> Targets:
        """Position controller to p_t [m; NED] with heading yaw_t [rad; NED]; ``climb``
        [m/s up] replaces the vertical position loop when given."""
        st = self.truth()
        p, v = st.p[self.i], st.v[self.i]
        if self.landed and climb is None and p_t[2] >= p[2] - 0.05:
            return 0.0, 0.0, yaw_t, 0.0
        v_des = KP_POS * (p_t[:2] - p[:2])
        n = float(np.linalg.norm(v_des))
        if n > MAX_SPEED:
            v_des *= MAX_SPEED / n
        a = KP_VEL * (v_des - v[:2])
        n = float(np.linalg.norm(a))
        if n > MAX_ACCEL:
            a *= MAX_ACCEL / n
        c, s = math.cos(yaw_t), math.sin(yaw_t)
        fwd, right = c * a[0] + s * a[1], -s * a[0] + c * a[1]
        g = self.params.g
        pitch, roll = -math.atan2(fwd, g), math.atan2(right, g)
        if climb is None:
            climb = min(max(KP_POS * (float(p[2]) - float(p_t[2])), -1.5), 2.5)
        thrust = self._climb_thrust(climb, 0.0) / (math.cos(roll) * math.cos(pitch))
        return roll, pitch, yaw_t, min(thrust, 1.0)

    def _land(self, t: float, vz: float) -> Targets:
        """Level descent at the landing speed; disarm once landed."""
        speed = self.flavour.land_speed(self.params_table)
        wait = float(self.flavour.disarm_delay(self.params_table))
        if self.landed and self.ground_since is not None and \
                t - self.ground_since >= AP_LAND_DETECT_S + wait:
            self.armed = False
            self.event(t, "landed")
            self.event(t, "disarmed")
        if self.position_ok(t):  # with a position: hold x, y while descending
            roll, pitch, yaw, thrust = self._hold(self.hold_p, self.hold_yaw, -speed)
            return roll, pitch, yaw, 0.0 if self.landed else thrust
        thrust = self._hover() * (1.0 + 0.4 * (vz - speed))  # NED: vz > 0 is down
        return 0.0, 0.0, self.hold_yaw, min(max(thrust, 0.0), 1.0)

    def _rtl(self, t: float) -> Targets:
        """Climb to the return altitude, fly home, then land there."""
        st = self.truth()
        p = st.p[self.i]
        if self.rtl_landing:
            return self._land(t, float(st.v[self.i, 2]))
        alt = float(self.flavour.rtl_altitude(self.params_table))
        z_t = min(float(self.hold_p[2]), float(self.home[2]) - alt)
        climbing = float(p[2]) > z_t + 0.2
        target = np.array([p[0], p[1], z_t]) if climbing else \
            np.array([self.home[0], self.home[1], z_t])
        if not climbing and float(np.linalg.norm(p[:2] - self.home[:2])) < 0.2 and \
                float(np.linalg.norm(st.v[self.i, :2])) < 0.3:
            self.rtl_landing = True
            self.hold_p = np.array([self.home[0], self.home[1], p[2]])
        return self._hold(target, self.hold_yaw)

    def _update_landed(self, t: float) -> None:
        """Land detector: on the ground for AP_LAND_DETECT_S (immediately when disarmed)."""
        if self.on_ground():
            if self.ground_since is None:
                self.ground_since = t
            self.landed = self.landed or not self.armed or \
                t - self.ground_since >= AP_LAND_DETECT_S
        else:
            self.ground_since = None
            self.landed = False
