"""Frame conventions and quaternion helpers (agent.flight.frames) against scipy."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from agent.flight import frames as fr

RNG = np.random.default_rng(7)


def test_enu_ned_vectors_round_trip_and_axes() -> None:
    v = RNG.normal(size=(50, 3))
    np.testing.assert_allclose(fr.ned_to_enu(fr.enu_to_ned(v)), v)
    np.testing.assert_allclose(fr.enu_to_ned([1.0, 2.0, 3.0]), [2.0, 1.0, -3.0])  # facts.md
    np.testing.assert_allclose(fr.frd_to_flu(fr.flu_to_frd(v)), v)
    np.testing.assert_allclose(fr.flu_to_frd([1.0, 2.0, 3.0]), [1.0, -2.0, -3.0])


@pytest.mark.parametrize("yaw", [0.0, 0.3, math.pi / 2, -2.5, 3.0])
def test_yaw_conversion(yaw: float) -> None:
    ned = fr.yaw_enu_to_ned(yaw)
    assert math.isclose(fr.wrap_pi(fr.yaw_ned_to_enu(ned) - yaw), 0.0, abs_tol=1e-12)
    # The heading vector agrees: ENU (cos, sin, 0) is NED (sin, cos, 0)... as enu_to_ned says.
    h_enu = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    np.testing.assert_allclose(fr.enu_to_ned(h_enu), [math.cos(ned), math.sin(ned), 0.0],
                               atol=1e-12)


def test_quaternion_matrix_euler_against_scipy() -> None:
    for _ in range(200):
        roll, pitch, yaw = RNG.uniform(-3, 3), RNG.uniform(-1.5, 1.5), RNG.uniform(-3, 3)
        q = fr.quat_from_euler(roll, pitch, yaw)
        ref = Rotation.from_euler("ZYX", [yaw, pitch, roll])  # eq. 2.2: Rz Ry Rx
        np.testing.assert_allclose(fr.quat_to_matrix(q), ref.as_matrix(), atol=1e-12)
        x, y, z, w = ref.as_quat()
        assert abs(abs(float(np.dot(q, [w, x, y, z]))) - 1.0) < 1e-12
        np.testing.assert_allclose(fr.quat_from_matrix(ref.as_matrix()), q, atol=1e-9)
        np.testing.assert_allclose(fr.euler_from_quat(q), [roll, pitch, yaw], atol=1e-9)
        assert math.isclose(fr.yaw_from_quat(q), yaw, abs_tol=1e-9)
        assert fr.quat_is_unit(q)


def test_quat_mul_conj() -> None:
    a, b = (fr.quat_normalize(RNG.normal(size=4)) for _ in range(2))
    ra, rb = fr.quat_to_matrix(a), fr.quat_to_matrix(b)
    np.testing.assert_allclose(fr.quat_to_matrix(fr.quat_mul(a, b)), ra @ rb, atol=1e-12)
    np.testing.assert_allclose(fr.quat_to_matrix(fr.quat_conj(a)), ra.T, atol=1e-12)


def test_attitude_enu_flu_ned_frd_round_trip_and_meaning() -> None:
    for _ in range(100):
        q = fr.quat_normalize(RNG.normal(size=4))
        q_ned = fr.quat_enu_flu_to_ned_frd(q)
        np.testing.assert_allclose(fr.quat_ned_frd_to_enu_flu(q_ned), q, atol=1e-9)
        # A body vector expressed either way lands on the same world vector.
        b_flu = RNG.normal(size=3)
        w_enu = fr.quat_to_matrix(q) @ b_flu
        w_ned = fr.quat_to_matrix(q_ned) @ fr.flu_to_frd(b_flu)
        np.testing.assert_allclose(fr.enu_to_ned(w_enu), w_ned, atol=1e-9)
    # Level, facing ENU yaw ψ ⇒ level, facing NED yaw π/2 − ψ.
    q_ned = fr.quat_enu_flu_to_ned_frd(fr.quat_from_euler(0.0, 0.0, 0.4))
    r, p, y = fr.euler_from_quat(q_ned)
    assert abs(r) < 1e-9 and abs(p) < 1e-9 and math.isclose(y, math.pi / 2 - 0.4)


def test_non_unit_and_bad_quaternions() -> None:
    assert not fr.quat_is_unit([1.0, 0.1, 0.0, 0.0])
    assert not fr.quat_is_unit([math.nan, 0.0, 0.0, 0.0])
    with pytest.raises(ValueError):
        fr.quat_normalize([0.0, 0.0, 0.0, 0.0])
