"""A gimbal's pitch limits as a constraint of the planner (agent.core.tilt; thesis eq. 2.3-2.5
and section 6.1: the tilt θ is the latitude of the camera direction v): the largest feasible
angular step against a walk along the great circle; runs that never command a tilt outside
the limits (and still never lose vision, Proposition 3); at the constrained optimum the
projected gradient, by finite differences of the reference vision, vanishes and the rest
points out of the limit; a brute-force search over θ and ψ within the limits finds nothing
better than the planner; limits that never bind leave the thesis' planner unchanged to the
bit; the runtime plans within the limits its vehicle reports.

The vision is recomputed with the reference eq. 3.1 (tests/reference.py), never taken from
the planner's bookkeeping."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from agent.clock import ManualClock
from agent.config.parse import load_scenario
from agent.core.orientation import angles_from_direction, direction_from_angles
from agent.core.planner import PlannerParams, integrate, plan_step
from agent.core.tilt import TiltLimits
from agent.net.memory import MemoryNetwork
from agent.runtime.shell.pose import KinematicPoseSource
from agent.runtime.shell.runtime import AgentConfig, AgentRuntime
from agent.storage.journal import Journal
from tests.conftest import scenario_path
from tests.reference import random_unit, vis_vec

Array = NDArray[np.float64]
D_OPT = 2.0
#: rounding allowed past a limit [rad]: a step cut at the limit lands on it to a few ulp
ULP = 1e-12


def tilt_of(v: Array) -> float:
    """θ [rad] of a unit direction (eq. 2.3)."""
    return angles_from_direction(v)[0]


def vis(p: Array, v: Array, q: Array, u: Array) -> float:
    """The reference vision (eq. 3.1, 3.4, 3.6) of one camera."""
    return float(vis_vec(p, v, q, u, D_OPT)[0])


def run(p: Array, v: Array, q: Array, u: Array, tilt: TiltLimits | None,
        params: PlannerParams, steps: int = 20000) -> tuple[Array, Array, list[Array]]:
    """Plan and integrate (eq. 5.1) until convergence: the final pose and every direction."""
    dirs = [v]
    for _ in range(steps):
        st = plan_step(p, v, q, u, D_OPT, params, tilt=tilt)
        if st.converged:
            break
        p, v = integrate(p, v, st.p_dot, st.omega, params.dt)
        dirs.append(v)
    return p, v, dirs


def floor_and_ceiling(side: str) -> tuple[Array, Array]:
    """30 landmarks on a floor patch below the camera start (normals up), or on a ceiling
    patch above it (normals down), 3 m ahead along x: the camera wants to look far down
    (or up), past the limits of :data:`LIMITS`."""
    rng = np.random.default_rng(1)
    xy = rng.uniform(-2.0, 2.0, (30, 2)) + np.array([3.0, 0.0])
    z = 0.0 if side == "floor" else 6.0
    q = np.c_[xy, np.full(30, z)]
    u = np.tile([0.0, 0.0, 1.0 if side == "floor" else -1.0], (30, 1))
    return q, u


LIMITS = TiltLimits(math.radians(-20.0), math.radians(15.0))
START = (np.array([0.0, 0.0, 3.0]), np.array([1.0, 0.0, 0.0]))


def test_max_step_is_where_the_great_circle_first_leaves_the_limits() -> None:
    """Against a dense walk along (v + α c)/‖·‖ (the integrator of eq. 5.1): every direction
    up to max_step is within the limits (widened to a start already past one), and the walk
    leaves them within one grid cell after it."""
    rng = np.random.default_rng(7)
    phis = np.linspace(0.0, math.pi / 2, 40001)[:-1]  # tan φ = α‖c‖
    checked_finite = 0
    for _ in range(300):  # cases, not landmarks
        a, b = np.sort(rng.uniform(-1.4, 1.4, 2))
        lim = TiltLimits(float(a), float(b))
        v = random_unit(rng)
        c = np.cross(random_unit(rng), v) * rng.uniform(0.2, 3.0)
        lo, hi = min(lim.lo, tilt_of(v)), max(lim.hi, tilt_of(v))
        alpha = np.tan(phis) / np.linalg.norm(c)
        w = v[None, :] + alpha[:, None] * c[None, :]
        th = np.arcsin(np.clip(w[:, 2] / np.linalg.norm(w, axis=1), -1.0, 1.0))
        out = np.flatnonzero((th < lo - ULP) | (th > hi + ULP))
        got = lim.max_step(v, c)
        if out.size == 0:
            assert got == math.inf or got >= alpha[-1]
            continue
        checked_finite += 1
        assert alpha[out[0] - 1] <= got <= alpha[out[0]] if out[0] > 0 else got <= alpha[1]
        w_got = v + got * c
        assert lo - ULP <= tilt_of(w_got / np.linalg.norm(w_got)) <= hi + ULP
    assert checked_finite > 100  # most cases do meet a limit


def test_projection_removes_only_the_outward_pitch_at_an_active_limit() -> None:
    lim = TiltLimits(-0.3, 0.2)
    psi = 0.7
    on_hi, inside = direction_from_angles(0.2, psi), direction_from_angles(0.0, psi)
    axis = np.array([math.sin(psi), -math.cos(psi), 0.0])  # v × ẑ / ‖·‖: its rate is θ̇
    yaw = np.cross(on_hi, axis)  # ⟂ v and ⟂ the pitch axis
    g = 2.0 * axis + 0.5 * yaw
    assert np.allclose(lim.project(on_hi, g), 0.5 * yaw)  # up is cut, yaw kept
    assert np.array_equal(lim.project(on_hi, -g), -g)  # down (inwards) is kept
    assert np.array_equal(lim.project(inside, g), g)  # no active limit: unchanged
    assert np.allclose(lim.project(direction_from_angles(-0.3, psi), -g), -0.5 * yaw)


def random_case(seed: int) -> tuple[Array, Array, Array, TiltLimits]:
    """Landmarks of a random cloud ahead of a camera at the origin, the camera's start
    direction and random tilt limits around its tilt."""
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(40, 3)) * [2.0, 2.0, 1.5] + [3.0, 0.0, 0.0]
    u = random_unit(rng, 40)
    th0, span = rng.uniform(-0.6, 0.6), rng.uniform(0.05, 0.5)
    lim = TiltLimits(th0 - rng.uniform(0.0, span), th0 + rng.uniform(0.0, span))
    return q, u, direction_from_angles(th0, rng.uniform(-0.5, 0.5)), lim


def test_runs_never_leave_the_limits_and_never_lose_vision() -> None:
    """Random clouds, random limits around a random start, 400 steps each: every direction
    the planner commands has its tilt within the limits, the reference vision never drops,
    and most runs are held by a limit at some step (else this would test nothing)."""
    held = 0
    for seed in range(6):  # runs, not landmarks
        q, u, v, lim = random_case(seed)
        p = np.zeros(3)
        values, at_limit = [vis(p, v, q, u)], False
        for _ in range(400):
            st = plan_step(p, v, q, u, D_OPT, PlannerParams(), tilt=lim)
            if st.converged:
                break
            p, v = integrate(p, v, st.p_dot, st.omega, 0.1)
            assert lim.lo - ULP <= tilt_of(v) <= lim.hi + ULP
            values.append(vis(p, v, q, u))
            at_limit |= any(lim.active(v))
        assert all(b >= a - 1e-12 * max(1.0, abs(a)) for a, b in itertools.pairwise(values))
        held += at_limit
    assert held >= 3


@pytest.mark.parametrize("side", ["floor", "ceiling"])
def test_projected_gradient_vanishes_at_the_constrained_optimum(side: str) -> None:
    """Converged (ω_min, ṗ_min small) with the camera on the limit the landmarks pull it
    past: by central differences of the reference vision, ∂/∂ψ and ∇_p vanish (the
    projected gradient) and ∂/∂θ points out of the limit (a KKT multiplier ≥ 0)."""
    q, u = floor_and_ceiling(side)
    params = PlannerParams(w_min=1e-5, p_min=1e-5)
    _p_free, v_free, _ = run(*START, q, u, None, PlannerParams())
    p, v, dirs = run(*START, q, u, LIMITS, params)
    th, psi = angles_from_direction(v)
    bound = LIMITS.lo if side == "floor" else LIMITS.hi
    free = tilt_of(v_free)
    assert (free < LIMITS.lo) if side == "floor" else (free > LIMITS.hi)  # it does bind
    assert abs(th - bound) < 1e-6
    assert all(LIMITS.lo - ULP <= tilt_of(d) <= LIMITS.hi + ULP for d in dirs)

    def f(theta: float, yaw: float, at: Array) -> float:
        return vis(at, direction_from_angles(theta, yaw), q, u)

    h = 1e-6
    d_th = (f(th + h, psi, p) - f(th - h, psi, p)) / (2 * h)
    d_psi = (f(th, psi + h, p) - f(th, psi - h, p)) / (2 * h)
    d_p = np.array([(f(th, psi, p + h * e) - f(th, psi, p - h * e)) / (2 * h)
                    for e in np.eye(3)])
    assert (d_th < 0.0) if side == "floor" else (d_th > 0.0)  # it pushes against the limit
    assert abs(d_psi) <= 1e-4 * abs(d_th) and np.linalg.norm(d_p) <= 1e-4 * abs(d_th)


@pytest.mark.parametrize("side", ["floor", "ceiling"])
def test_brute_force_over_the_tilt_within_the_limits_agrees(side: str) -> None:
    """At the planner's final position, every camera direction with its tilt in the limits
    (θ × ψ grid) sees no more than the planner's (converged with small ω_min, ṗ_min), and
    the best of them is the planner's tilt (to the grid's resolution)."""
    q, u = floor_and_ceiling(side)
    p, v, _ = run(*START, q, u, LIMITS, PlannerParams(w_min=1e-5, p_min=1e-5))
    th, psi = angles_from_direction(v)
    planned = vis(p, v, q, u)
    thetas = np.linspace(LIMITS.lo, LIMITS.hi, 351)
    yaws = np.linspace(-math.pi, math.pi, 721)
    best, arg = -np.inf, (0.0, 0.0)
    for t in thetas:  # rows of the grid, each vectorised over ψ
        dirs = np.stack([np.cos(t) * np.cos(yaws), np.cos(t) * np.sin(yaws),
                         np.full(yaws.size, np.sin(t))], axis=1)
        vals = vis_vec(np.tile(p, (yaws.size, 1)), dirs, q, u, D_OPT)
        k = int(np.argmax(vals))
        if vals[k] > best:
            best, arg = float(vals[k]), (float(t), float(yaws[k]))
    assert best <= planned * (1.0 + 1e-9)
    assert best >= planned * (1.0 - 1e-3)
    assert abs(arg[0] - th) <= thetas[1] - thetas[0]
    assert abs((arg[1] - psi + math.pi) % (2 * math.pi) - math.pi) <= 2 * (yaws[1] - yaws[0])


def test_limits_that_never_bind_leave_the_thesis_planner_unchanged() -> None:
    """No limit (the default) and limits wider than the run's tilts: bit for bit the
    thesis' planner."""
    for seed in range(3):
        q, u, v, _lim = random_case(seed)
        p0, v0, dirs0 = run(np.zeros(3), v, q, u, None, PlannerParams(), steps=300)
        th = np.array([tilt_of(d) for d in dirs0])
        wide = TiltLimits.of(float(th.min()) - 0.05, float(th.max()) + 0.05)
        for lim in (TiltLimits(), wide):
            p1, v1, dirs1 = run(np.zeros(3), v, q, u, lim, PlannerParams(), steps=300)
            assert np.array_equal(p1, p0) and np.array_equal(v1, v0)
            assert len(dirs1) == len(dirs0) and all(
                np.array_equal(a, b) for a, b in zip(dirs0, dirs1, strict=True))


class GimballedVehicle(KinematicPoseSource):
    """A kinematic vehicle (eq. 5.1) whose gimbal reports tilt limits; it records the tilt
    of every direction it is commanded to."""

    limits = TiltLimits(-0.05, 0.05)
    tilts: list[float]

    def tilt_limits(self) -> TiltLimits:
        """The gimbal's pitch range [rad]."""
        return self.limits

    def command(self, p_dot: Array, omega: Array, dt: float) -> None:
        super().command(p_dot, omega, dt)
        self.tilts.append(tilt_of(self.v))


def test_the_runtime_plans_within_the_limits_its_vehicle_reports(tmp_path: Path) -> None:
    """An agent of the cube (section 6.2) on a vehicle whose gimbal allows ±0.05 rad: every
    tilt commanded over its optimisation is within them, and it is held at one."""
    sc = load_scenario(scenario_path("cube_6_2"))
    clock = ManualClock()
    spec = sc.agents[0]
    vehicle = GimballedVehicle(spec.p0, spec.v0, clock, sc.space)
    vehicle.tilts = []
    journal = Journal(tmp_path / "A")
    rt = AgentRuntime("A", sc, MemoryNetwork().transport("A"), journal, clock, pose=vehicle,
                      config=AgentConfig(mission="m"))
    rt.start()
    try:
        for _ in range(600):
            rt.tick()
            if rt.phase != "optimising":
                break
            clock.advance(sc.params.dt)
    finally:
        rt.stop()
        journal.close()
    tilts = np.array(vehicle.tilts)
    assert tilts.size > 10
    assert tilts.min() >= -0.05 - ULP and tilts.max() <= 0.05 + ULP
    assert np.min(np.abs(np.abs(tilts) - 0.05)) < 1e-9  # a limit held it
