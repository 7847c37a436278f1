"""Force to attitude (section 6.1) against an independent scipy construction."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from agent.flight import frames as fr
from agent.flight.attitude import (
    ThrustModel,
    force_to_attitude,
    force_to_attitude_ned,
    level_attitude,
    limit_force_ned,
)

MODEL = ThrustModel(mass=1.2, hover_thrust=0.45, thrust_min=0.05, thrust_max=0.95,
                    tilt_max=math.radians(40))


def _reference_ned(f_ned: np.ndarray, yaw: float) -> Rotation:
    """Independent: find roll α, pitch β with Rz(ψ) Ry(β) Rx(α) e_z = −F̂ (NED, body z down)."""
    f = Rotation.from_euler("z", -yaw).apply(-f_ned / np.linalg.norm(f_ned))
    alpha = -math.asin(f[1])
    beta = math.atan2(f[0], f[2])
    return Rotation.from_euler("ZYX", [yaw, beta, alpha])


def _reference_enu(f_enu: np.ndarray, yaw: float) -> Rotation:
    """Independent: Rz(ψ) Ry(β) Rx(α) e_z = +F̂ in ENU with body FLU (z up)."""
    f = Rotation.from_euler("z", -yaw).apply(f_enu / np.linalg.norm(f_enu))
    alpha = -math.asin(f[1])
    beta = math.atan2(f[0], f[2])
    return Rotation.from_euler("ZYX", [yaw, beta, alpha])


def _random_feasible(rng: np.random.Generator) -> np.ndarray:
    """A force [N, ENU] inside the tilt and thrust limits (so no limiting happens)."""
    while True:
        up = rng.uniform(0.6, 1.6) * MODEL.weight
        tilt = rng.uniform(0.0, MODEL.tilt_max * 0.95)
        az = rng.uniform(-math.pi, math.pi)
        h = up * math.tan(tilt)
        f = np.array([h * math.cos(az), h * math.sin(az), up])
        n = np.linalg.norm(f)
        if MODEL.force_of(MODEL.thrust_min) < n < MODEL.force_of(MODEL.thrust_max):
            return f


def _same_rotation(q_wxyz: np.ndarray, ref: Rotation) -> None:
    x, y, z, w = ref.as_quat()
    assert abs(abs(float(np.dot(q_wxyz, [w, x, y, z]))) - 1.0) < 1e-9


def test_ned_convention_matches_scipy() -> None:
    rng = np.random.default_rng(1)
    for _ in range(300):
        f_ned = fr.enu_to_ned(_random_feasible(rng))
        yaw = rng.uniform(-math.pi, math.pi)
        cmd = force_to_attitude_ned(f_ned, yaw, MODEL)
        ref = _reference_ned(f_ned, yaw)
        _same_rotation(cmd.q, ref)
        r, p, _ = ref.as_euler("ZYX")[::-1]
        np.testing.assert_allclose([cmd.roll, cmd.pitch], [r, p], atol=1e-9)
        assert abs(fr.wrap_pi(cmd.yaw - yaw)) < 1e-9
        # Thrust along −z_B realises the force; T = T_hover ‖F‖ / (m g).
        thrust_dir = -ref.apply([0.0, 0.0, 1.0])
        np.testing.assert_allclose(thrust_dir * MODEL.force_of(cmd.thrust), f_ned, atol=1e-9)
        assert math.isclose(cmd.thrust, MODEL.hover_thrust * np.linalg.norm(f_ned) / MODEL.weight)


def test_enu_convention_matches_scipy() -> None:
    rng = np.random.default_rng(2)
    for _ in range(300):
        f_enu = _random_feasible(rng)
        yaw = rng.uniform(-math.pi, math.pi)
        cmd = force_to_attitude(f_enu, yaw, MODEL)
        ref = _reference_enu(f_enu, yaw)
        # The NED/FRD command is the ENU/FLU attitude seen through the frame changes.
        _same_rotation(fr.quat_ned_frd_to_enu_flu(cmd.q), ref)
        assert abs(fr.wrap_pi(fr.yaw_from_quat(fr.quat_ned_frd_to_enu_flu(cmd.q)) - yaw)) < 1e-9


def test_hover_is_level_at_hover_thrust() -> None:
    cmd = force_to_attitude([0.0, 0.0, MODEL.weight], 0.7, MODEL)
    assert math.isclose(cmd.thrust, MODEL.hover_thrust)
    assert abs(cmd.roll) < 1e-12 and abs(cmd.pitch) < 1e-12
    lvl = level_attitude(0.2, MODEL)
    assert lvl.thrust == MODEL.hover_thrust and lvl.roll == 0.0 and lvl.pitch == 0.0
    assert math.isclose(lvl.yaw, 0.2)


@pytest.mark.parametrize("seed", range(5))
def test_limits_tilt_and_thrust(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for _ in range(100):
        f = rng.normal(size=3) * 40.0
        f_lim = limit_force_ned(f, MODEL)
        tilt = math.atan2(math.hypot(f_lim[0], f_lim[1]), -f_lim[2])
        assert tilt <= MODEL.tilt_max + 1e-9
        cmd = force_to_attitude_ned(f, rng.uniform(-3, 3), MODEL)
        assert MODEL.thrust_min - 1e-12 <= cmd.thrust <= MODEL.thrust_max + 1e-12
        cos_tilt = min(1.0, math.cos(cmd.roll) * math.cos(cmd.pitch))
        assert math.acos(cos_tilt) <= MODEL.tilt_max + 1e-9
        assert fr.quat_is_unit(cmd.q, 1e-12)


def test_downward_force_keeps_minimum_thrust_upright() -> None:
    cmd = force_to_attitude([3.0, 0.0, -50.0], 0.0, MODEL)  # asks to push down: impossible
    assert cmd.thrust == pytest.approx(MODEL.thrust_min)
    assert math.cos(cmd.roll) * math.cos(cmd.pitch) > 0  # still upright


def test_rejects_non_finite() -> None:
    with pytest.raises(ValueError):
        force_to_attitude([math.nan, 0.0, 10.0], 0.0, MODEL)
    with pytest.raises(ValueError):
        force_to_attitude([0.0, 0.0, 10.0], math.inf, MODEL)
    with pytest.raises(ValueError):
        ThrustModel(hover_thrust=0.95, thrust_max=0.9)
