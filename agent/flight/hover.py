"""Online hover-thrust estimation: which normalised thrust balances m g right now.

The hover thrust T_h is airframe-, battery- and payload-specific (ArduCopter MOT_THST_HOVER,
default 0.35, range 0.2-0.8; PX4 MPC_THR_HOVER) and drifts in flight. A wrong T_h in the
thrust model (:class:`agent.flight.attitude.ThrustModel`) scales every vertical command:
the drone climbs into the ceiling (T_h too high) or sinks (too low).

Model (inspired by PX4's ``mc_hover_thrust_estimator``, ``ZeroOrderHoverThrustEkf`` in
src/modules/mc_hover_thrust_estimator/zero_order_hover_thrust_ekf.hpp; re-derived here,
not copied):

* state x = T_h, a random walk: x[k+1] = x[k] + w, w ~ N(0, q² dt) (q [1/√s]);
* measurement: the vertical acceleration a_z [m/s²; world, up positive] with the vertical
  part of the normalised thrust T_z = T cos(tilt) applied just before,
  a_z = h(x) + v = g (T_z / T_h − 1) + v, v ~ N(0, R);
* H = ∂h/∂T_h = −g T_z / T_h²; scalar Kalman update, T_h kept in [bounds];
* innovation gating: the normalised innovation squared ν² / (gate² S) must be < 1;
  if the low-passed, signed test ratio stays above ``offset_ratio`` (many rejections of one
  sign: the hover thrust really jumped, e.g. a payload), the state variance is inflated so
  the filter re-converges (PX4's recovery idea);
* R is learnt from the de-biased residual (Akhlaghi et al. 2017, as PX4 does),
  R ← (1 − α) R + α (r² + H² P), bounded;
* valid when the variance P has stayed below ``valid_var`` for ``valid_hold_s`` (PX4: 1e-3
  and a 2 s hysteresis; false at once when P grows again).

Pure: time t [s] is passed in; no I/O and no clocks.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from agent.flight.flavours import flavour


@dataclass(frozen=True)
class HoverConfig:
    """Estimator tuning. Defaults follow PX4's parameters where one exists: HTE_HT_NOISE
    0.0036 [1/s], HTE_HT_ERR_INIT 0.1, HTE_ACC_GATE 3 SD; bounds [0.1, 0.9] (normalised)."""

    process_noise: float = 0.0036  #: q, hover-thrust random walk [1/√s]
    initial_std: float = 0.1  #: 1-σ of the seed (normalised thrust)
    gate: float = 3.0  #: innovation gate [standard deviations]
    accel_var: float = 5.0  #: initial R [(m/s²)²]
    accel_var_min: float = 1.0  #: bounds on the learnt R [(m/s²)²]
    accel_var_max: float = 400.0
    noise_tau_s: float = 2.0  #: time constant of the R learning [s]
    offset_tau_s: float = 1.0  #: time constant of the residual / test-ratio low-pass [s]
    offset_ratio: float = 0.2  #: |low-passed signed test ratio| that triggers recovery
    recovery_gain: float = 1e3  #: P += gain · q² dt per rejected step while recovering
    lo: float = 0.1  #: hover-thrust bounds (normalised)
    hi: float = 0.9
    valid_var: float = 1e-3  #: P below this counts towards validity (σ ≈ 0.032)
    valid_hold_s: float = 2.0  #: P must stay low this long [s] before the estimate is valid
    max_dt_s: float = 1.0  #: longer gaps restart the time base (no prediction over them)
    g: float = 9.81  #: gravity [m/s²]

    def __post_init__(self) -> None:
        if not 0.0 < self.lo < self.hi < 1.0:
            raise ValueError("hover bounds must satisfy 0 < lo < hi < 1")
        if min(self.process_noise, self.initial_std, self.gate, self.accel_var_min) <= 0:
            raise ValueError("noise, gate and variance settings must be > 0")
        if not self.accel_var_min <= self.accel_var <= self.accel_var_max:
            raise ValueError("accel_var must lie within [accel_var_min, accel_var_max]")


@dataclass(frozen=True)
class HoverEstimate:
    """One step's result: hover thrust T_h (normalised), its variance, whether it is valid,
    the innovation [m/s²], its test ratio (< 1 fused) and whether the sample was fused."""

    hover_thrust: float
    variance: float
    valid: bool
    innovation: float
    test_ratio: float
    fused: bool


def predicted_accel_up(thrust_up: float, hover_thrust: float, g: float = 9.81) -> float:
    """Measurement model h: vertical acceleration [m/s²; world, up] that the vertical
    normalised thrust T_z produces when T_h balances gravity: g (T_z / T_h − 1)."""
    return g * (thrust_up / hover_thrust - 1.0)


def hover_seed_from_params(autopilot: str, params: dict[str, float], default: float,
                           config: HoverConfig | None = None) -> float:
    """Seed T_h from the autopilot's own value (its flavour's ``hover_param`` in ``params``:
    MOT_THST_HOVER, MPC_THR_HOVER), else ``default``; clamped into the estimator bounds
    (ValueError, one line, for an unknown autopilot)."""
    cfg = config or HoverConfig()
    value = params.get(flavour(autopilot).hover_param, default)
    if not math.isfinite(value):
        value = default
    return min(max(float(value), cfg.lo), cfg.hi)


class HoverThrustEstimator:
    """Scalar Kalman filter of the hover thrust (see the module docstring for the model)."""

    def __init__(self, seed: float, config: HoverConfig | None = None) -> None:
        self.cfg = config or HoverConfig()
        self.hover_thrust: float = seed
        self.reset(seed)

    def reset(self, seed: float | None = None) -> None:
        """Restart from ``seed`` (or the current estimate) with the initial uncertainty, e.g.
        on the ground before take-off."""
        c = self.cfg
        start = self.hover_thrust if seed is None else seed
        if not math.isfinite(start):
            raise ValueError("hover-thrust seed must be finite")
        self.hover_thrust = min(max(float(start), c.lo), c.hi)
        self.variance = c.initial_std ** 2
        self.accel_var = c.accel_var
        self.valid = False
        self._low_since: float | None = None
        self._t_prev: float | None = None
        self._residual_lpf = 0.0
        self._ratio_lpf = 0.0

    @property
    def std(self) -> float:
        """1-σ of the hover-thrust estimate (normalised thrust)."""
        return math.sqrt(self.variance)

    def update(self, t: float, accel_up: float, thrust_up: float) -> HoverEstimate:
        """Fuse one sample at time t [s]: measured vertical acceleration ``accel_up``
        [m/s²; world, up positive] and the vertical normalised thrust ``thrust_up`` that
        produced it (T cos tilt, 0..1). Call only while armed and in the air."""
        c = self.cfg
        if not (math.isfinite(t) and math.isfinite(accel_up) and math.isfinite(thrust_up)):
            return self._result(0.0, math.inf, False)
        dt = 0.0 if self._t_prev is None else t - self._t_prev
        if dt < 0.0 or dt > c.max_dt_s:
            dt = 0.0  # time went back or a long gap: no prediction over it
        self._t_prev = t
        self.variance += c.process_noise ** 2 * dt  # predict: x constant, P grows

        h = -c.g * thrust_up / self.hover_thrust ** 2
        s = max(h * h * self.variance + self.accel_var, self.accel_var)
        innov = accel_up - predicted_accel_up(thrust_up, self.hover_thrust, c.g)
        ratio = innov * innov / (c.gate ** 2 * s)
        fused = ratio < 1.0
        residual = innov
        if fused:
            k = self.variance * h / s
            self.hover_thrust = min(max(self.hover_thrust + k * innov, c.lo), c.hi)
            self.variance = min(max((1.0 - k * h) * self.variance, 1e-10), 1.0)
            residual = accel_up - predicted_accel_up(thrust_up, self.hover_thrust, c.g)
        elif abs(self._ratio_lpf) > c.offset_ratio:
            self.variance = min(self.variance + c.recovery_gain * c.process_noise ** 2 * dt, 1.0)

        if dt > 0.0:
            a_off = dt / (c.offset_tau_s + dt)
            self._residual_lpf += a_off * (residual - self._residual_lpf)
            signed = math.copysign(min(ratio, 1.0), innov)
            self._ratio_lpf += a_off * (signed - self._ratio_lpf)
            a_noise = dt / (c.noise_tau_s + dt)
            r = residual - self._residual_lpf
            learnt = (1.0 - a_noise) * self.accel_var + a_noise * (r * r + h * h * self.variance)
            self.accel_var = min(max(learnt, c.accel_var_min), c.accel_var_max)

        self._update_validity(t, ratio)
        return self._result(innov, ratio, fused)

    def _update_validity(self, t: float, ratio: float) -> None:
        """Valid once P < valid_var for valid_hold_s (and, when becoming valid, the last
        test ratio < 1); invalid at once when P rises again."""
        low = self.variance < self.cfg.valid_var and (self.valid or ratio < 1.0)
        if not low:
            self._low_since, self.valid = None, False
            return
        if self._low_since is None:
            self._low_since = t
        self.valid = self.valid or t - self._low_since >= self.cfg.valid_hold_s

    def _result(self, innov: float, ratio: float, fused: bool) -> HoverEstimate:
        return HoverEstimate(self.hover_thrust, self.variance, self.valid, innov, ratio, fused)


class AccelFromVelocity:
    """Acceleration [m/s²; world ENU, gravity not included] from successive velocity samples
    (e.g. motion capture's), by finite differences with a first-order low-pass of time
    constant ``tau_s`` [s]. A gap longer than ``max_dt_s`` [s] or time running backwards
    restarts it. Feeds :class:`HoverThrustEstimator` through
    :attr:`agent.flight.controllers.FlightState.a`."""

    def __init__(self, tau_s: float = 0.03, max_dt_s: float = 0.25) -> None:
        if not (tau_s >= 0.0 and max_dt_s > 0.0):
            raise ValueError("tau_s must be >= 0 and max_dt_s > 0")
        self.tau_s, self.max_dt_s = tau_s, max_dt_s
        self._t: float | None = None
        self._v: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._a: tuple[float, float, float] | None = None

    def reset(self) -> None:
        """Forget the history (e.g. after the vehicle landed)."""
        self._t, self._a = None, None

    def update(self, t: float, vel: Iterable[float]) -> tuple[float, float, float] | None:
        """Velocity ``vel`` [m/s; world ENU] at time t [s]; the filtered acceleration, or None
        until two samples less than ``max_dt_s`` apart have arrived."""
        v = tuple(float(x) for x in vel)
        if len(v) != 3 or not all(math.isfinite(x) for x in (t, *v)):
            return self._a
        prev_t, prev_v = self._t, self._v
        self._t, self._v = t, (v[0], v[1], v[2])
        if prev_t is None:
            return None
        dt = t - prev_t
        if dt <= 0.0 or dt > self.max_dt_s:
            self._a = None
            return None
        raw = [(v[i] - prev_v[i]) / dt for i in range(3)]
        if self._a is not None:
            k = dt / (self.tau_s + dt)
            raw = [a + k * (r - a) for a, r in zip(self._a, raw, strict=True)]
        self._a = (raw[0], raw[1], raw[2])
        return self._a
