"""Low-level controllers of thesis section 6.1 (figures 6.1 and 6.2), pure and stateful
only in their integrators. Mission frames: world ENU, forces in N, velocities in m/s.

* :class:`SpeedController`: PID on the velocity error → desired force F* (figure 6.1).
* :class:`PositionController`: PID on the position error → F* (figure 6.2, trading and
  initial positioning); :class:`YawController`: PI on the yaw error → yaw rate (figure 6.2).
* :class:`LatitudeIntegrator`: the simulated camera tilt θ, integrated from θ̇ (eq. 2.5).
* :func:`limit_velocity_to_space` / :func:`clip_to_space`: keep commands inside Ω.
* :class:`FlightController`: the two loops together, velocity mode (pose optimisation) or
  hold mode (trading), producing NED attitude set-points through :mod:`agent.flight.attitude`.
  With a :class:`agent.flight.hover.HoverThrustEstimator` and measured accelerations it
  re-estimates the hover thrust of its thrust model at run time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from agent.flight.attitude import AttitudeCommand, ThrustModel, force_to_attitude
from agent.flight.frames import wrap_pi, yaw_enu_to_ned
from agent.flight.hover import HoverThrustEstimator

Array = NDArray[np.float64]
_UP = np.array([0.0, 0.0, 1.0])


def _vec3(x: ArrayLike | float) -> Array:
    """A float or 3-sequence as a (3,) float array (per-axis gains)."""
    return np.broadcast_to(np.asarray(x, dtype=np.float64), (3,)).copy()


@dataclass
class PidGains:
    """Per-axis PID gains on an error in m or m/s giving an acceleration [m/s²]; ``i_limit``
    bounds the integral's contribution [m/s²]; the integrator runs only on axes whose error is
    within ``i_band`` [m or m/s]; both take a scalar or an (x, y, z) triple; ``a_max``
    (horizontal, vertical) bounds the output."""

    kp: ArrayLike = (2.5, 2.5, 3.0)
    ki: ArrayLike = (0.6, 0.6, 1.0)
    kd: ArrayLike = (0.0, 0.0, 0.0)
    i_limit: ArrayLike = 2.0
    i_band: ArrayLike = math.inf
    a_max_xy: float = 5.0
    a_max_z: float = 4.0


def _limit_accel(a: Array, g: PidGains) -> Array:
    """Acceleration [m/s², ENU] with horizontal norm ≤ a_max_xy and |vertical| ≤ a_max_z."""
    out = a.copy()
    h = math.hypot(out[0], out[1])
    if h > g.a_max_xy:
        out[0:2] *= g.a_max_xy / h
    out[2] = min(max(out[2], -g.a_max_z), g.a_max_z)
    return out


class _Pid:
    """Vector PID with conditional-integration anti-windup and a clamped integrator."""

    def __init__(self, gains: PidGains) -> None:
        self.g = gains
        self.kp, self.ki, self.kd = _vec3(gains.kp), _vec3(gains.ki), _vec3(gains.kd)
        self.i_limit, self.i_band = _vec3(gains.i_limit), _vec3(gains.i_band)
        self.integral = np.zeros(3)

    def reset(self) -> None:
        """Clear the integral [error · s]."""
        self.integral = np.zeros(3)

    def step(self, err: Array, derr: Array, dt: float) -> Array:
        """Acceleration [m/s²] = kp e + ki ∫e + kd ė, limited; integrates only when that
        does not push a saturated output further (anti-windup)."""
        raw = self.kp * err + self.ki * self.integral + self.kd * derr
        out = _limit_accel(raw, self.g)
        saturated = ~np.isclose(raw, out)
        frozen = (saturated & (np.sign(err) == np.sign(raw))) | (np.abs(err) > self.i_band)
        if dt > 0.0:
            new = self.integral + np.where(frozen, 0.0, err * dt)
            with np.errstate(divide="ignore", invalid="ignore"):
                cap = np.where(self.ki > 0, self.i_limit / self.ki, 0.0)
            self.integral = np.clip(new, -cap, cap)
        return out


class SpeedController:
    """Figure 6.1: PID from commanded velocity v* [m/s, ENU] to F* = m (a_pid + a_ff) + m g ẑ
    [N, ENU]."""

    def __init__(self, model: ThrustModel, gains: PidGains | None = None) -> None:
        self.model = model
        self.pid = _Pid(gains or PidGains())
        self._prev_err: Array | None = None

    def reset(self) -> None:
        """Clear the integrator and the derivative memory."""
        self.pid.reset()
        self._prev_err = None

    def update(self, v_des: ArrayLike, v: ArrayLike, dt: float,
               a_ff: ArrayLike | None = None) -> Array:
        """Fig. 6.1 speed loop: v* and measured v [m/s, ENU], step dt [s] → F* [N, ENU]."""
        err = np.asarray(v_des, dtype=np.float64) - np.asarray(v, dtype=np.float64)
        derr = np.zeros(3) if self._prev_err is None or dt <= 0 else (err - self._prev_err) / dt
        self._prev_err = err
        a = self.pid.step(err, derr, dt)
        if a_ff is not None:
            a = _limit_accel(a + np.asarray(a_ff, dtype=np.float64), self.pid.g)
        return self.model.mass * (a + self.model.g * _UP)


class PositionController:
    """Figure 6.2: PID from the position error [m, ENU] (derivative on the measured velocity)
    to F* [N, ENU]."""

    def __init__(self, model: ThrustModel, gains: PidGains | None = None) -> None:
        self.model = model
        self.pid = _Pid(gains or PidGains(kp=(3.0, 3.0, 4.0), ki=(0.4, 0.4, 1.0),
                                          kd=(3.0, 3.0, 3.5), i_limit=2.0, i_band=0.25))

    def reset(self) -> None:
        """Clear the integrator."""
        self.pid.reset()

    def update(self, p_des: ArrayLike, p: ArrayLike, v: ArrayLike, dt: float) -> Array:
        """Fig. 6.2 position loop: target p* and measured p [m], v [m/s] (ENU) → F* [N, ENU]."""
        err = np.asarray(p_des, dtype=np.float64) - np.asarray(p, dtype=np.float64)
        a = self.pid.step(err, -np.asarray(v, dtype=np.float64), dt)
        return self.model.mass * (a + self.model.g * _UP)


class YawController:
    """Figure 6.2: PI on the wrapped yaw error [rad] → yaw rate ψ̇ [rad/s] (ENU, about +z)."""

    def __init__(self, kp: float = 1.5, ki: float = 0.1, rate_max: float = math.pi / 4,
                 i_limit: float = 0.2) -> None:
        self.kp, self.ki, self.rate_max, self.i_limit = kp, ki, rate_max, i_limit
        self.integral = 0.0

    def reset(self) -> None:
        """Clear the integrator."""
        self.integral = 0.0

    def update(self, yaw_des: float, yaw: float, dt: float) -> float:
        """Fig. 6.2 angle loop: ψ* and measured ψ [rad, ENU] → ψ̇* [rad/s], anti-windup PI."""
        err = wrap_pi(yaw_des - yaw)
        raw = self.kp * err + self.ki * self.integral
        out = min(max(raw, -self.rate_max), self.rate_max)
        if out == raw and dt > 0:
            cap = self.i_limit / self.ki if self.ki > 0 else 0.0
            self.integral = min(max(self.integral + err * dt, -cap), cap)
        return out


@dataclass
class LatitudeIntegrator:
    """Section 6.1: the camera latitude θ [rad] is simulated, θ ← θ + θ̇ dt with θ̇ from eq. 2.5,
    kept within [−lat_max, lat_max]."""

    theta: float = 0.0
    lat_max: float = math.pi / 2 - 1e-3

    def step(self, omega: ArrayLike, psi: float, dt: float) -> float:
        """Eq. 2.5: integrate θ̇ = sin ψ ω₁ − cos ψ ω₂ (ω [rad/s, world ENU]) over dt [s]."""
        theta_dot, _ = lat_lon_rates(omega, self.theta, psi)
        self.theta = min(max(self.theta + theta_dot * dt, -self.lat_max), self.lat_max)
        return self.theta


def lat_lon_rates(omega: ArrayLike, theta: float, psi: float) -> tuple[float, float]:
    """Eq. 2.5 θ̇ = sin ψ ω₁ − cos ψ ω₂ and the longitude rate ψ̇ [rad/s] of v(θ, ψ) under
    v̇ = ω × v (ω world ENU): ψ̇ = ω₃ − tan θ (cos ψ ω₁ + sin ψ ω₂), which is eq. 2.4 (ψ̇ = ω₃)
    at θ = 0."""
    w = np.asarray(omega, dtype=np.float64)
    s, c = math.sin(psi), math.cos(psi)
    return float(s * w[0] - c * w[1]), float(w[2] - math.tan(theta) * (c * w[0] + s * w[1]))


def yaw_rate_of(omega: ArrayLike, theta: float = 0.0, psi: float = 0.0) -> float:
    """Section 6.1: the yaw rate γ̇ is the longitude rate ψ̇ (eq. 2.4: ω₃ at θ = 0; the exact
    rate of :func:`lat_lon_rates` otherwise) [rad/s]."""
    return lat_lon_rates(omega, theta, psi)[1]


def clip_to_space(p: ArrayLike, lo: ArrayLike, hi: ArrayLike, margin: float = 0.0) -> Array:
    """Position [m, ENU] clipped into Ω = [lo + margin, hi − margin] (infinite bounds allowed)."""
    lo_a = np.asarray(lo, dtype=np.float64) + margin
    hi_a = np.asarray(hi, dtype=np.float64) - margin
    with np.errstate(invalid="ignore"):  # inf + (−inf) on unbounded axes: not used there
        mid = np.where(lo_a > hi_a, 0.5 * (lo_a + hi_a), np.nan)
    out = np.clip(np.asarray(p, dtype=np.float64), np.minimum(lo_a, hi_a), np.maximum(lo_a, hi_a))
    return np.where(np.isnan(mid), out, mid)


def limit_velocity_to_space(p: ArrayLike, v: ArrayLike, lo: ArrayLike, hi: ArrayLike,
                            margin: float, a_brake: float, k_wall: float = 1.5) -> Array:
    """Velocity [m/s, ENU] whose outward part per axis is at most min(√(2 a_brake d), k_wall d),
    d the distance [m] to the wall shrunk by ``margin``; past that limit (d < 0) the axis is
    driven back inward at k_wall |d|."""
    pa, va = np.asarray(p, dtype=np.float64), np.asarray(v, dtype=np.float64).copy()
    d_hi = np.asarray(hi, dtype=np.float64) - margin - pa
    d_lo = pa - (np.asarray(lo, dtype=np.float64) + margin)

    def cap(d: Array) -> Array:
        """Largest outward speed [m/s] at wall distance d [m] (negative past the limit)."""
        with np.errstate(invalid="ignore"):
            c = np.minimum(np.sqrt(2 * a_brake * np.maximum(d, 0.0)), k_wall * d)
        return np.where(np.isfinite(d), c, np.inf)

    return np.clip(va, -cap(d_lo), cap(d_hi))


@dataclass
class FlightState:
    """Measured state for the controllers: position [m], velocity [m/s] (world ENU), yaw ψ
    [rad, ENU], time t [s, simulation clock] and, if measured, the acceleration a
    [m/s², world ENU] (kinematic, gravity removed) that feeds the hover-thrust estimator;
    ``on_ground`` while armed and still on the ground."""

    p: Array
    v: Array
    yaw: float
    t: float
    a: Array | None = None
    on_ground: bool = False  #: armed but not yet off the ground (take-off)


@dataclass
class AttitudeSetpoint:
    """What the driver sends: the section 6.1 command plus the body yaw-rate feed-forward
    [rad/s, FRD z, i.e. −ψ̇_ENU]."""

    cmd: AttitudeCommand
    yaw_rate_frd: float


@dataclass
class FlightConfig:
    """Controller configuration: thrust model, gains, mission space Ω [m, ENU] with a wall
    ``margin`` [m], braking acceleration for the wall limit [m/s²], largest yaw lead [rad],
    and the lift-off search (an airframe heavier than its autopilot's hover thrust says)."""

    model: ThrustModel = field(default_factory=ThrustModel)
    speed_gains: PidGains | None = None
    position_gains: PidGains | None = None
    lo: ArrayLike = (-np.inf, -np.inf, -np.inf)
    hi: ArrayLike = (np.inf, np.inf, np.inf)
    margin: float = 0.1
    a_brake: float = 1.0
    yaw_lead_max: float = 0.3
    liftoff_delay_s: float = 1.0  #: on the ground wanting to climb this long [s]: ...
    liftoff_ramp: float = 0.15  #: ... raise the hover thrust this fast [1/s] until lift-off


class FlightController:
    """Figures 6.1/6.2 together. ``velocity`` mode tracks (ṗ*, ψ̇*) from the planner; ``hold``
    mode holds a position and yaw. Outputs NED attitude set-points; inputs are ENU.

    ``model`` is the thrust model in use: ``cfg.model`` with its hover thrust replaced at run
    time by ``hover`` (an estimator fed with each state's measured acceleration ``s.a`` and
    the vertical thrust commanded one step before) or by :meth:`set_hover_thrust`. Unlike
    PX4, which waits for a valid estimate, every estimate is used at once: a seed can be off
    by a factor 2.5 and the velocity loop's integrator alone cannot carry that."""

    def __init__(self, config: FlightConfig | None = None,
                 hover: HoverThrustEstimator | None = None) -> None:
        self.cfg = config or FlightConfig()
        self.model = self.cfg.model
        self.hover = hover
        self._thrust_up: float | None = None
        m = self.cfg.model
        self.speed = SpeedController(m, self.cfg.speed_gains)
        self.position = PositionController(m, self.cfg.position_gains)
        self.yaw_pi = YawController()
        self.mode = "hold"
        self.v_des = np.zeros(3)
        self.yaw_rate_des = 0.0
        self.until = math.inf
        self.p_hold: Array | None = None
        self.yaw_hold: float | None = None
        self._yaw_sp: float | None = None
        self._t_prev: float | None = None
        self._climb_on_ground_s = 0.0

    def reset(self) -> None:
        """Clear every integrator (e.g. at take-off: nothing integrated on the ground)."""
        self.speed.reset()
        self.position.reset()
        self.yaw_pi.reset()
        self._yaw_sp = None
        self._thrust_up = None
        self._climb_on_ground_s = 0.0

    def set_hover_thrust(self, hover_thrust: float) -> None:
        """Use hover thrust T_h (normalised) from now on, e.g. one read from the autopilot."""
        self.model = self.model.with_hover_thrust(hover_thrust)

    def set_velocity(self, p_dot: ArrayLike, yaw_rate: float,
                     until: float = math.inf) -> None:
        """Velocity mode: ṗ* [m/s, ENU] and ψ̇* [rad/s] (eq. 2.4) until time ``until`` [s], then
        hold where it is; ValueError (state unchanged) on non-finite input."""
        v = np.asarray(p_dot, dtype=np.float64)
        if v.shape != (3,) or not np.all(np.isfinite(v)) or not math.isfinite(yaw_rate):
            raise ValueError("velocity command must be finite")
        if self.mode != "velocity":
            self.speed.reset()
        self.mode, self.v_des, self.yaw_rate_des = "velocity", v.copy(), float(yaw_rate)
        self.until = until

    def set_hold(self, p: ArrayLike | None = None, yaw: float | None = None) -> None:
        """Hold mode (fig. 6.2) at p* [m, ENU] and ψ* [rad, ENU]; None = where it is next update."""
        if p is not None:
            pa = np.asarray(p, dtype=np.float64)
            if pa.shape != (3,) or not np.all(np.isfinite(pa)):
                raise ValueError("hold position must be a finite 3-vector")
            p = clip_to_space(pa, self.cfg.lo, self.cfg.hi, self.cfg.margin)
        if yaw is not None and not math.isfinite(yaw):
            raise ValueError("hold yaw must be finite")
        if self.mode != "hold":
            self.position.reset()
            self.yaw_pi.reset()
        self.mode, self.p_hold, self.yaw_hold = "hold", p, yaw

    def update(self, s: FlightState) -> AttitudeSetpoint:
        """One control step from measured state ``s`` (dt from the previous call's time)."""
        dt = 0.0 if self._t_prev is None else max(0.0, min(s.t - self._t_prev, 0.2))
        self._t_prev = s.t
        cfg = self.cfg
        if self.hover is not None and s.a is not None and self._thrust_up is not None:
            est = self.hover.update(s.t, float(s.a[2]), self._thrust_up)
            self.set_hover_thrust(est.hover_thrust)
        if self.mode == "velocity" and s.t > self.until:
            self.set_hold()  # the command expired: hold where it is
        if self.mode == "hold":
            if self.p_hold is None:
                self.p_hold = clip_to_space(s.p, cfg.lo, cfg.hi, cfg.margin)
            if self.yaw_hold is None:
                self.yaw_hold = s.yaw
            force = self.position.update(self.p_hold, s.p, s.v, dt)
            rate = self.yaw_pi.update(self.yaw_hold, s.yaw, dt)
        else:
            v_des = limit_velocity_to_space(s.p, self.v_des, cfg.lo, cfg.hi, cfg.margin,
                                            cfg.a_brake)
            force = self.speed.update(v_des, s.v, dt)
            rate = self.yaw_rate_des
        # Yaw set-point: integrate ψ̇* but never lead the measured yaw by more than yaw_lead_max.
        ysp = s.yaw if self._yaw_sp is None else self._yaw_sp + rate * dt
        lead = wrap_pi(ysp - s.yaw)
        ysp = s.yaw + min(max(lead, -cfg.yaw_lead_max), cfg.yaw_lead_max)
        self._yaw_sp = wrap_pi(ysp)
        self._search_liftoff(s.on_ground and force[2] > self.model.weight, dt)
        cmd = force_to_attitude(force, self._yaw_sp, self.model)
        self._thrust_up = cmd.thrust * float(-cmd.force_ned[2] / np.linalg.norm(cmd.force_ned))
        return AttitudeSetpoint(cmd, -rate)

    def _search_liftoff(self, climbing_on_ground: bool, dt: float) -> None:
        """Take-off on an airframe heavier than its seed says (the hover thrust too low, so
        the largest commanded acceleration never lifts it): after ``liftoff_delay_s`` on
        the ground wanting to climb, raise the hover thrust by ``liftoff_ramp`` per second
        (up to 0.05 below the thrust limit) and restart the estimator there; it converges
        once airborne. The ground reaction hides the weight, so nothing else can learn it."""
        if not climbing_on_ground:
            self._climb_on_ground_s = 0.0
            return
        self._climb_on_ground_s += dt
        if self._climb_on_ground_s <= self.cfg.liftoff_delay_s:
            return
        m = self.model
        raised = min(m.hover_thrust + self.cfg.liftoff_ramp * dt, m.thrust_max - 0.05)
        if raised > m.hover_thrust:
            self.set_hover_thrust(raised)
            if self.hover is not None:
                self.hover.reset(raised)

    def yaw_setpoint_ned(self) -> float | None:
        """Current yaw set-point [rad, NED], if any."""
        return None if self._yaw_sp is None else yaw_enu_to_ned(self._yaw_sp)
