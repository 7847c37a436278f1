"""Hover-thrust estimation (agent.flight.hover) and the vertical loop that uses it, closed
around a small pure vehicle model written here."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from agent.flight.attitude import ThrustModel
from agent.flight.controllers import FlightConfig, FlightController, FlightState, PidGains
from agent.flight.hover import (
    HoverConfig,
    HoverThrustEstimator,
    hover_seed_from_params,
    predicted_accel_up,
)

G = 9.81


def _feed(est: HoverThrustEstimator, hover_true: float, t0: float, seconds: float,
          rng: np.random.Generator, noise: float = 0.5, rate: float = 50.0) -> float:
    """Open-loop samples: thrust wandering around the true hover, a = g (T/T_h − 1) + noise."""
    t = t0
    for _ in range(int(seconds * rate)):
        thrust = hover_true * (1.0 + 0.1 * math.sin(2.0 * t))
        est.update(t, predicted_accel_up(thrust, hover_true) + rng.normal(0.0, noise), thrust)
        t += 1.0 / rate
    return t


def test_measurement_model_is_zero_at_hover() -> None:
    assert predicted_accel_up(0.35, 0.35) == 0.0
    assert predicted_accel_up(0.7, 0.35) == pytest.approx(G)  # twice the hover thrust: +1 g


def test_converges_and_becomes_valid() -> None:
    est = HoverThrustEstimator(0.5)
    assert not est.valid and est.std == pytest.approx(0.1)
    rng = np.random.default_rng(1)
    t = _feed(est, 0.3, 0.0, 1.0, rng)
    assert not est.valid  # validity needs valid_hold_s (2 s) of low variance
    _feed(est, 0.3, t, 9.0, rng)
    assert est.hover_thrust == pytest.approx(0.3, abs=0.01)
    assert est.valid and est.variance < 1e-3
    est.reset(0.5)
    assert not est.valid and est.hover_thrust == 0.5


def test_outlier_is_gated_and_bounds_hold() -> None:
    est = HoverThrustEstimator(0.4)
    rng = np.random.default_rng(2)
    t = _feed(est, 0.4, 0.0, 5.0, rng)
    before = est.hover_thrust
    r = est.update(t, 60.0, 0.4)  # a 6 g spike (a bump, a bad sample)
    assert not r.fused and r.test_ratio > 1.0 and est.hover_thrust == before
    assert not est.update(t + 0.02, math.nan, 0.4).fused  # non-finite input: ignored
    low = HoverThrustEstimator(0.15, HoverConfig(lo=0.1, hi=0.9))
    _feed(low, 0.05, 0.0, 10.0, rng)  # data say 0.05: outside the physical bounds
    assert low.hover_thrust >= 0.1


def test_recovers_after_a_payload_step() -> None:
    """The true hover thrust jumps 0.35 → 0.455 (+30 % mass): samples are rejected at first,
    the recovery logic inflates the variance and the estimate follows within 10 s."""
    est = HoverThrustEstimator(0.35)
    rng = np.random.default_rng(3)
    t = _feed(est, 0.35, 0.0, 10.0, rng)
    assert est.valid
    _feed(est, 0.455, t, 10.0, rng)
    assert est.hover_thrust == pytest.approx(0.455, abs=0.01)


def test_seed_from_autopilot_parameters() -> None:
    assert hover_seed_from_params("ardupilot", {"MOT_THST_HOVER": 0.27}, 0.35) == 0.27
    assert hover_seed_from_params("px4", {"MPC_THR_HOVER": 0.42}, 0.5) == 0.42
    assert hover_seed_from_params("px4", {}, 0.5) == 0.5  # not read: the caller's default
    assert hover_seed_from_params("ardupilot", {"MOT_THST_HOVER": 0.02}, 0.35) == 0.1  # bounds
    with pytest.raises(ValueError):
        hover_seed_from_params("betaflight", {}, 0.5)


def test_thrust_model_takes_a_run_time_hover_thrust() -> None:
    m = ThrustModel(hover_thrust=0.5)
    m2 = m.with_hover_thrust(0.3)
    assert m2.hover_thrust == 0.3 and m2.mass == m.mass and m.hover_thrust == 0.5
    assert m2.thrust_of(m2.weight) == pytest.approx(0.3)  # level hover at the new value
    assert m.with_hover_thrust(0.99).hover_thrust < m.thrust_max  # stays a valid model


# -- closed loop ------------------------------------------------------------------------------

@dataclass
class _Vertical:
    """Vertical dynamics m z'' = T_max · thrust · cos(tilt) − m g − drag(ż), first-order motor
    lag τ; T_max = m₀ g / (true hover thrust). Integrated at 500 Hz."""

    hover_true: float
    mass: float = 1.5
    tau: float = 0.05
    z: float = 1.0
    vz: float = 0.0
    motor: float = 0.5
    accel: float = 0.0

    def __post_init__(self) -> None:
        self.t_max = self.mass * G / self.hover_true

    def step(self, thrust_cmd: float, cos_tilt: float, duration: float) -> None:
        dt = 0.002
        for _ in range(round(duration / dt)):
            self.motor += (thrust_cmd - self.motor) * dt / self.tau
            drag = 0.3 * self.vz + 0.05 * self.vz * abs(self.vz)
            self.accel = (self.t_max * self.motor * cos_tilt - self.mass * G - drag) / self.mass
            self.vz += self.accel * dt
            self.z += self.vz * dt


_NO_INTEGRAL = PidGains(kp=(3.0, 3.0, 4.0), ki=(0.4, 0.4, 0.0), kd=(3.0, 3.0, 3.5),
                        i_limit=2.0, i_band=0.25)


def _fly(hover_true: float, *, estimator: bool = True, gains: PidGains | None = None,
         seconds: float = 25.0, mass_step_at: float | None = None,
         target: float = 1.5) -> tuple[np.ndarray, np.ndarray, FlightController]:
    """Hold (0, 0, target) from 1 m at 50 Hz; the thrust model is seeded with 0.5. The
    accelerometer reads the true vertical acceleration + N(0, 0.3²) m/s²."""
    rng = np.random.default_rng(7)
    fc = FlightController(FlightConfig(model=ThrustModel(hover_thrust=0.5), position_gains=gains),
                          hover=HoverThrustEstimator(0.5) if estimator else None)
    fc.set_hold([0.0, 0.0, target], 0.0)
    v = _Vertical(hover_true)
    ts, zs = [], []
    for k in range(int(seconds * 50)):
        t = k * 0.02
        if mass_step_at is not None and k == int(mass_step_at * 50):
            v.mass *= 1.3  # a 30 % heavier payload: the true hover thrust rises 30 %
        a_meas = np.array([0.0, 0.0, v.accel + rng.normal(0.0, 0.3)])
        sp = fc.update(FlightState(np.array([0.0, 0.0, v.z]), np.array([0.0, 0.0, v.vz]),
                                   0.0, t, a=a_meas))
        v.step(sp.cmd.thrust, math.cos(sp.cmd.roll) * math.cos(sp.cmd.pitch), 0.02)
        ts.append(t + 0.02)
        zs.append(v.z)
    return np.array(ts), np.array(zs), fc


def _worst_error(ts: np.ndarray, zs: np.ndarray, after: float, target: float = 1.5) -> float:
    """Largest |z − target| [m] from time ``after`` [s] to the end."""
    return float(np.max(np.abs(zs[ts >= after] - target)))


@pytest.mark.parametrize("hover_true", [0.2, 0.35, 0.5, 0.7])
def test_altitude_settles_for_any_hover_thrust(hover_true: float) -> None:
    """Seed 0.5, true hover 0.2..0.7: within 0.1 m of the target from 8 s on (the estimate
    within 0.02 of the truth), never more than 0.75 m above it."""
    ts, zs, fc = _fly(hover_true)
    assert _worst_error(ts, zs, 8.0) < 0.1
    assert zs.max() < 1.5 + 0.75
    assert fc.model.hover_thrust == pytest.approx(hover_true, abs=0.02)


@pytest.mark.parametrize("hover_true", [0.35, 0.5])
def test_altitude_settles_after_a_mass_step(hover_true: float) -> None:
    """+30 % mass at 20 s (hover 0.35 → 0.455, 0.5 → 0.65): back within 0.1 m by 30 s."""
    ts, zs, fc = _fly(hover_true, seconds=40.0, mass_step_at=20.0)
    before = ts < 20.0
    assert _worst_error(ts[before], zs[before], 8.0) < 0.1
    assert _worst_error(ts, zs, 30.0) < 0.1
    assert fc.model.hover_thrust == pytest.approx(1.3 * hover_true, abs=0.02)


@pytest.mark.parametrize("hover_true", [0.2, 0.35, 0.7])
def test_without_estimator_and_integral_it_does_not_settle(hover_true: float) -> None:
    """The old loop (fixed hover 0.5, no vertical integral): off by > 0.1 m for good (0.35:
    ~0.74 m above, 0.7: ~1 m below, 0.2: climbs without limit)."""
    ts, zs, _ = _fly(hover_true, estimator=False, gains=_NO_INTEGRAL)
    assert _worst_error(ts, zs, 20.0) > 0.1


def test_integral_alone_is_not_enough() -> None:
    """The position loop's integral (band 0.25 m) alone does not remove a hover-thrust error:
    the P term's offset (~0.74 m for 0.35) lies outside its band, and 0.2 climbs away; the
    estimator is what holds altitude on any airframe."""
    ts, zs, _ = _fly(0.35, estimator=False)
    assert _worst_error(ts, zs, 20.0) > 0.5
    ts, zs, _ = _fly(0.2, estimator=False, seconds=10.0)
    assert zs[-1] > 5.0  # climbing away


def test_acceleration_from_mocap_velocity() -> None:
    """Finite differences of the velocity, low-passed: a constant 2 m/s² up is read exactly;
    a gap longer than max_dt_s restarts it; non-finite samples are ignored."""
    from agent.flight.hover import AccelFromVelocity

    acc = AccelFromVelocity(tau_s=0.03, max_dt_s=0.25)
    assert acc.update(0.0, [0.0, 0.0, 0.0]) is None
    a = None
    for k in range(1, 50):
        a = acc.update(0.01 * k, [0.0, 0.0, 2.0 * 0.01 * k])
    assert a is not None and a[2] == pytest.approx(2.0) and a[0] == 0.0
    assert acc.update(0.49 + 0.01, [0.0, 0.0, math.nan]) == a  # ignored
    assert acc.update(2.0, [0.0, 0.0, 0.0]) is None  # a 1.5 s gap: start again
