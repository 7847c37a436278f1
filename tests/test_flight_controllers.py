"""Controllers of section 6.1 / figure 6.2 (pure, no I/O)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.flight.attitude import ThrustModel
from agent.flight.controllers import (
    FlightConfig,
    FlightController,
    FlightState,
    LatitudeIntegrator,
    PidGains,
    PositionController,
    SpeedController,
    YawController,
    clip_to_space,
    lat_lon_rates,
    limit_velocity_to_space,
    yaw_rate_of,
)
from agent.flight.frames import yaw_ned_to_enu

MODEL = ThrustModel()


def test_speed_controller_hover_and_direction() -> None:
    sc = SpeedController(MODEL)
    f = sc.update(np.zeros(3), np.zeros(3), 0.02)
    np.testing.assert_allclose(f, [0.0, 0.0, MODEL.weight])
    f = sc.update([1.0, 0.0, 0.0], np.zeros(3), 0.02)
    assert f[0] > 0 and abs(f[1]) < 1e-12 and f[2] == pytest.approx(MODEL.weight, rel=1e-3)


def test_speed_controller_anti_windup() -> None:
    gains = PidGains(kp=1.0, ki=2.0, i_limit=1.0, a_max_xy=2.0)
    sc = SpeedController(MODEL, gains)
    for _ in range(1000):  # huge error: output saturated, the integral must not run away
        sc.update([10.0, 0.0, 0.0], np.zeros(3), 0.02)
    assert sc.pid.integral[0] <= 1.0 / 2.0 + 1e-12
    f = sc.update([0.0, 0.0, 0.0], np.zeros(3), 0.02)  # error gone: small residual only
    assert abs(f[0]) <= MODEL.mass * 1.0 + 1e-9


def test_position_controller_converges_on_double_integrator() -> None:
    pc = PositionController(MODEL)
    p, v, dt = np.array([0.0, 0.0, 0.0]), np.zeros(3), 0.01
    target = np.array([1.0, -0.5, 1.0])
    for _ in range(1500):
        f = pc.update(target, p, v, dt)
        a = f / MODEL.mass - np.array([0.0, 0.0, MODEL.g])
        v = v + a * dt
        p = p + v * dt
    np.testing.assert_allclose(p, target, atol=0.01)


def test_yaw_pi_wraps_and_limits() -> None:
    yc = YawController(kp=2.0, rate_max=0.5)
    assert yc.update(3.0, -3.0, 0.01) < 0  # shortest way across ±π
    assert abs(yc.update(2.0, -1.0, 0.01)) <= 0.5


def test_latitude_integrator_is_eq_2_5() -> None:
    li = LatitudeIntegrator()
    omega, psi = np.array([0.3, -0.2, 0.1]), 0.7
    theta_dot, psi_dot = lat_lon_rates(omega, 0.0, psi)
    assert math.isclose(li.step(omega, psi, 0.5), 0.5 * theta_dot)
    assert math.isclose(theta_dot, math.sin(psi) * 0.3 - math.cos(psi) * -0.2)
    assert yaw_rate_of(omega) == psi_dot == 0.1  # eq. 2.4 at θ = 0
    for _ in range(1000):
        li.step(omega, psi, 1.0)
    assert li.theta <= math.pi / 2


def test_lat_lon_rates_follow_omega_cross_v() -> None:
    from agent.core.orientation import direction_from_angles

    rng = np.random.default_rng(3)
    for _ in range(50):
        theta, psi = rng.uniform(-1.2, 1.2), rng.uniform(-3, 3)
        omega = rng.normal(size=3)
        td, pd = lat_lon_rates(omega, theta, psi)
        h = 1e-6
        v = direction_from_angles(theta, psi)
        v_next = direction_from_angles(theta + td * h, psi + pd * h)
        np.testing.assert_allclose((v_next - v) / h, np.cross(omega, v), atol=1e-4)


def test_space_limits() -> None:
    lo, hi = np.array([-2.0, -2.0, 0.0]), np.array([2.0, 2.0, 3.0])
    np.testing.assert_allclose(clip_to_space([5.0, -9.0, 1.0], lo, hi, 0.1), [1.9, -1.9, 1.0])
    v = limit_velocity_to_space([1.9, 0.0, 1.0], [1.0, -1.0, 0.0], lo, hi, 0.1, 1.0)
    np.testing.assert_allclose(v, [0.0, -1.0, 0.0])  # at the wall: outward part removed
    v = limit_velocity_to_space([1.4, 0.0, 1.0], [3.0, 0.0, 0.0], lo, hi, 0.1, 0.2)
    assert v[0] == pytest.approx(math.sqrt(2 * 0.2 * 0.5))
    v = limit_velocity_to_space([1.4, 0.0, 1.0], [3.0, 0.0, 0.0], lo, hi, 0.1, 5.0, k_wall=1.0)
    assert v[0] == pytest.approx(0.5)
    v = limit_velocity_to_space([2.1, 0.0, 1.0], [0.0, 0.0, 0.0], lo, hi, 0.1, 1.0, k_wall=1.0)
    assert v[0] == pytest.approx(-0.2)  # past the limit: pushed back in
    v = limit_velocity_to_space([0.0, 0.0, 1.0], [0.3, 0.0, 0.0], [-np.inf] * 3, [np.inf] * 3,
                                0.1, 1.0)
    np.testing.assert_allclose(v, [0.3, 0.0, 0.0])


def test_flight_controller_modes_and_guards() -> None:
    fc = FlightController(FlightConfig(lo=(-2, -2, 0), hi=(2, 2, 3)))
    with pytest.raises(ValueError):
        fc.set_velocity([math.nan, 0, 0], 0.0)
    with pytest.raises(ValueError):
        fc.set_hold([0.0, 0.0, math.inf])
    fc.set_hold([10.0, 0.0, 1.0])
    assert fc.p_hold is not None and fc.p_hold[0] == pytest.approx(1.9)  # never outside Ω
    fc.set_velocity([0.2, 0.0, 0.0], 0.1, until=1.0)
    s = FlightState(np.array([0.0, 0.0, 1.0]), np.zeros(3), 0.0, 0.0)
    sp = fc.update(s)
    assert fc.mode == "velocity" and sp.yaw_rate_frd == -0.1
    assert sp.cmd.pitch < 0  # NED pitch down = accelerate forward (east here)
    fc.update(FlightState(s.p, s.v, 0.0, 1.5))
    assert fc.mode == "hold"  # the command expired
    sp = fc.update(FlightState(s.p, s.v, 0.0, 1.6))
    assert yaw_ned_to_enu(sp.cmd.yaw) == pytest.approx(0.0, abs=0.05)
