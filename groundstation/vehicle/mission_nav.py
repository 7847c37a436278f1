"""How the simulated autopilot flies a mission in AUTO: straight legs and the controller that
tracks them (the item-by-item logic is :mod:`groundstation.vehicle.mission_exec`).

A leg from ``start`` to ``end`` [m; local NED] is flown by a target point moving along the
straight line with a trapezoidal speed profile: it accelerates at ``accel`` [m/s²] to the leg's
speed, cruises, and decelerates to rest at the end (the shape of ArduCopter's S-curve,
libraries/AC_WPNav/AC_WPNav.cpp, and of PX4's jerk-limited trajectory, without their jerk
limit). The speed along the line is the largest whose horizontal part stays within the
horizontal speed and whose vertical part within the climb / descent speed of the flavour
(:func:`leg_speeds`). :func:`track` follows the moving target with its velocity and
acceleration as feed-forwards, through position and velocity loops (:data:`KP_POS_AUTO`,
:data:`KP_VEL_AUTO`) on the autopilot's hover-thrust parameter, and turns the heading towards
the wanted yaw at most at the autopilot's yaw slew rate (the flavour's flight ``yaw_slew``:
ArduCopter ATC_SLEW_YAW 6000 cdeg/s, libraries/AC_AttitudeControl; PX4 MPC_YAWRAUTO_MAX
45 °/s, src/modules/mc_pos_control): a
quadrotor does not spin its heading about in a step, and a yaw-locked gimbal has to keep up
with it.

Like the autopilot's other controllers, the simulation navigates on the true state (the
EKF's error is what the telemetry and the camera report on top of it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agent.flight.frames import wrap_pi
from groundstation.vehicle.control import MAX_SPEED

Array = NDArray[np.float64]
Targets = tuple[float, float, float, float]

#: Position [1/s] and velocity [1/s] gains of the tracking controller: with the target's
#: velocity and acceleration fed forward it stays within centimetres of a leg, as the
#: autopilots' position controllers (with their integrators) do.
KP_POS_AUTO, KP_VEL_AUTO = 2.0, 4.0
#: Largest horizontal acceleration the tracking controller asks for [m/s²] (the leg itself
#: accelerates at the flavour's WPNAV_ACCEL / MPC_ACC_HOR; the rest corrects errors).
MAX_ACCEL_AUTO = 5.0
#: Legs shorter than this horizontally keep the heading [m] (ArduCopter WPNAV_YAW_DIST_MIN,
#: 200 cm: a short track leaves the yaw where it is).
YAW_MIN_TRACK = 2.0


@dataclass(frozen=True)
class Speeds:
    """A flavour's mission speeds: horizontal, climb, descent [m/s], acceleration [m/s²]."""

    horizontal: float
    up: float
    down: float
    accel: float


def leg_speeds(s: Speeds, override: float | None) -> Speeds:
    """The mission speeds ``s`` of the autopilot's parameters (the flavour's flight:
    ArduCopter WPNAV_SPEED, WPNAV_SPEED_UP / _DN [cm/s], WPNAV_ACCEL [cm/s²]; PX4
    MPC_XY_CRUISE, MPC_Z_V_AUTO_UP / _DN [m/s], MPC_ACC_HOR [m/s²]), bounded below;
    ``override`` [m/s] (DO_CHANGE_SPEED) replaces the horizontal speed."""
    horizontal = override if override is not None and override > 0 else s.horizontal
    return Speeds(max(horizontal, 0.2), max(s.up, 0.1), max(s.down, 0.1), max(s.accel, 0.2))


class Leg:
    """A straight leg flown by a target with a trapezoidal speed profile (module docstring):
    ``start``, ``end`` [m; NED], started at ``t0`` [s sim]."""

    def __init__(self, start: Array, end: Array, speeds: Speeds, t0: float) -> None:
        self.start = np.asarray(start, dtype=np.float64).copy()
        self.end = np.asarray(end, dtype=np.float64).copy()
        self.t0 = t0
        d = self.end - self.start
        self.length = float(np.linalg.norm(d))
        self.unit = d / self.length if self.length > 1e-9 else np.zeros(3)
        limits = [math.inf]
        horizontal = float(np.hypot(self.unit[0], self.unit[1]))
        if horizontal > 1e-9:
            limits.append(speeds.horizontal / horizontal)
        vertical = float(self.unit[2])  # NED: > 0 descends
        if vertical > 1e-9:
            limits.append(speeds.down / vertical)
        elif vertical < -1e-9:
            limits.append(speeds.up / -vertical)
        self.speed = min(limits) if self.length > 1e-9 else 0.0
        self.accel = speeds.accel
        if self.length <= self.speed**2 / self.accel:  # triangular profile
            self.t_acc = math.sqrt(self.length / self.accel)
            self.t_cruise = 0.0
            self.speed = self.accel * self.t_acc
        else:
            self.t_acc = self.speed / self.accel
            self.t_cruise = (self.length - self.speed * self.t_acc) / self.speed
        self.duration = 2.0 * self.t_acc + self.t_cruise

    @property
    def horizontal(self) -> float:
        """Horizontal length [m]."""
        return float(np.hypot(*(self.end[:2] - self.start[:2])))

    def done(self, t: float) -> bool:
        """The target has come to rest at the end by t [s sim]."""
        return t - self.t0 >= self.duration

    def at(self, t: float) -> tuple[Array, Array, Array]:
        """The target's position [m; NED], velocity [m/s; NED] and acceleration [m/s²; NED]
        at t [s sim]."""
        tau = min(max(t - self.t0, 0.0), self.duration)
        a, ta, tc = self.accel, self.t_acc, self.t_cruise
        if tau >= self.duration:
            return self.end.copy(), np.zeros(3), np.zeros(3)
        if tau < ta:
            s, v, acc = 0.5 * a * tau**2, a * tau, a
        elif tau < ta + tc:
            s, v, acc = 0.5 * a * ta**2 + self.speed * (tau - ta), self.speed, 0.0
        else:
            rest = self.duration - tau
            s, v, acc = self.length - 0.5 * a * rest**2, a * rest, -a
        return self.start + s * self.unit, v * self.unit, acc * self.unit


def bearing(a: Array, b: Array) -> float:
    """Heading [rad; NED, from north] of the horizontal line a → b."""
    return math.atan2(float(b[1] - a[1]), float(b[0] - a[0]))


def slew_yaw(current: float, wanted: float, rate: float, dt: float) -> float:
    """``current`` turned towards ``wanted`` [rad] by at most ``rate`` · ``dt``."""
    err = wrap_pi(wanted - current)
    step = rate * max(dt, 0.0)
    return wrap_pi(current + min(max(err, -step), step))


def track(ap: Any, p_t: Array, v_ff: Array, a_ff: Array, yaw: float,
          speeds: Speeds) -> Targets:
    """(roll, pitch, yaw [rad; NED], thrust) that fly autopilot ``ap``'s vehicle along the
    target p_t [m; NED] moving at v_ff [m/s; NED] and accelerating at a_ff [m/s²; NED],
    heading ``yaw`` [rad]; on the ground with the target not above it, the motors idle."""
    st = ap.truth()
    p, v = st.p[ap.i], st.v[ap.i]
    if ap.landed and float(p_t[2]) >= float(p[2]) - 0.05 and float(v_ff[2]) >= 0.0:
        return 0.0, 0.0, yaw, 0.0
    v_des = v_ff[:2] + KP_POS_AUTO * (p_t[:2] - p[:2])
    cap = MAX_SPEED + float(np.linalg.norm(v_ff[:2]))
    n = float(np.linalg.norm(v_des))
    if n > cap:
        v_des = v_des * (cap / n)
    acc = a_ff[:2] + KP_VEL_AUTO * (v_des - v[:2])
    n = float(np.linalg.norm(acc))
    if n > MAX_ACCEL_AUTO:
        acc = acc * (MAX_ACCEL_AUTO / n)
    c, s = math.cos(yaw), math.sin(yaw)
    fwd, right = c * acc[0] + s * acc[1], -s * acc[0] + c * acc[1]
    g = ap.params.g
    pitch, roll = -math.atan2(fwd, g), math.atan2(right, g)
    climb = -float(v_ff[2]) + KP_POS_AUTO * (float(p[2]) - float(p_t[2]))  # [m/s up]
    climb = min(max(climb, -(speeds.down + 0.5)), speeds.up + 0.5)
    a_up = -float(a_ff[2]) + KP_VEL_AUTO * (climb + float(v[2]))  # NED: −v_z is up
    thrust = ap._hover() * (1.0 + a_up / g) / (math.cos(roll) * math.cos(pitch))
    return roll, pitch, yaw, min(max(thrust, 0.0), 1.0)
