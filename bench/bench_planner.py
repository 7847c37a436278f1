"""Planner micro-benchmark: one full planner step against the number of landmarks.

One step = visible set, both gradients (eq. 3.15-3.16), collision avoidance against 10
obstacles (6 walls + 4 other agents, smooth mode), and the line searches for the linear and
the angular velocity (Algorithm 6).

Per m (each with median, p90 and max wall time, and the median CPU time of this process):
- ``planner_step``: every step of a whole pose optimisation (landmarks on a wall, 4 agents
  elsewhere in the room), with the number of steps the avoidance deflected;
- ``planner_step_crowded``: the same with the 4 agents in the camera's way, so that most
  steps are deflected and the line search backtracks far (small accepted steps);
- ``planner_step_converged``: the camera at its optimum, where no candidate passes the
  Armijo test (the worst case of the plain search, which evaluates every candidate; the
  certified bounds of agent/core/linesearch.py reject them without evaluating most).
And ``safe_direction``: problem 4.11 with 10 active constraints and an infeasible p_opt
(the full candidate enumeration).
Also ``vision_gradients_loop``: a per-landmark Python loop for vision + both gradients at
m = 1,000, the style this project replaces (for comparison only).

Run: ``python -m bench.bench_planner``.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from collections.abc import Callable
from functools import partial
from typing import Any, TextIO

import numpy as np

from agent.core.avoidance import MissionSpace, safe_direction
from agent.core.planner import PlannerParams, PlanStep, integrate, plan_step
from agent.core.vision import Landmarks, gradients
from bench.timing import time_calls

SIZES = (1_000, 3_000, 10_000, 30_000, 100_000)


def _scene(m: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """m landmarks on the face x = 4 of a wall, normals facing −x with some spread."""
    rng = np.random.default_rng(seed)
    q = np.column_stack([np.full(m, 4.0), rng.uniform(0.5, 4.5, m), rng.uniform(0.2, 2.8, m)])
    u = np.array([-1.0, 0.0, 0.0]) + 0.3 * rng.normal(size=(m, 3))
    return q, u / np.linalg.norm(u, axis=1)[:, None]


#: Other agents [m]: "open" keeps them off the camera's path, "crowded" puts them in its way.
OTHERS = {
    "open": np.array([[0.6, 0.6, 2.4], [0.6, 4.4, 0.6], [3.0, 4.4, 2.6], [3.0, 0.6, 0.4]]),
    "crowded": np.array([[1.6, 3.6, 1.5], [2.2, 1.2, 1.2], [3.0, 4.2, 2.5], [3.0, 0.8, 0.5]]),
}


def _setup(scene: str = "open") -> tuple[PlannerParams, MissionSpace, np.ndarray]:
    params = PlannerParams(avoidance="smooth", r_s=1.0, d_w=0.5)
    space = MissionSpace(np.array([0.0, 0.0, 0.0]), np.array([5.0, 5.0, 3.0]))
    return params, space, OTHERS[scene]


def _emit(out: TextIO, rec: dict[str, Any]) -> None:
    out.write(json.dumps(rec) + "\n")
    out.flush()


def _loop_vision_gradients(p: np.ndarray, v: np.ndarray, q: np.ndarray, u: np.ndarray,
                           d_opt: float) -> tuple[float, np.ndarray, np.ndarray]:
    """Reference style only: eq. 3.8/3.15/3.16 one landmark at a time."""
    total, gp, a = 0.0, np.zeros(3), np.zeros(3)
    for qi, ui in zip(q, u, strict=True):
        d = qi - p
        r = float(np.linalg.norm(d))
        dv, du = float(d @ v), float(d @ ui)
        if dv <= 0 or du >= 0:
            continue
        fb = np.exp(1 - r / d_opt) / (d_opt * r)
        fbp = -fb * (1 / d_opt + 1 / r)
        total += fb * dv * -du
        gp += fbp / r * du * dv * d + fb * (dv * ui + du * v)
        a += fb * -du * d
    return total, gp, np.cross(v, a)


def _trajectory(lm: Landmarks, params: PlannerParams, space: MissionSpace,
                others: np.ndarray, steps: int = 3000) -> tuple[list[float], list[float], int,
                                                                 np.ndarray, np.ndarray]:
    """Time every planner step of one pose optimisation; returns (wall times, CPU times,
    n_avoiding, p, v)."""
    p, v = np.array([0.4, 2.5, 1.5]), np.array([0.8, 0.6, 0.0])
    times: list[float] = []
    cpu: list[float] = []
    avoiding = 0
    for _ in range(steps):
        s = _timed(partial(plan_step, p, v, lm, None, 2.0, params, space, others), times, cpu)
        if s.converged:
            break
        avoiding += int(np.any(s.p_dir) and float(s.p_dir @ s.grad_p) <
                        float(np.linalg.norm(s.grad_p)) * (1 - 1e-9))
        p, v = integrate(p, v, s.p_dot, s.omega, params.dt)
    return times, cpu, avoiding, p, v


def _timed(fn: Callable[[], PlanStep], wall: list[float], cpu: list[float]) -> PlanStep:
    """Call ``fn``, appending its wall time and this process's CPU time [s] (the CPU time is
    less sensitive to other processes on a shared machine)."""
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    wall.append(time.perf_counter() - t0)
    cpu.append(time.process_time() - c0)
    return out


def _stats(wall: list[float], cpu: list[float]) -> dict[str, float]:
    """Median, p90 and max wall time and the median CPU time [s]."""
    return {"median_s": statistics.median(wall), "p90_s": float(np.percentile(wall, 90)),
            "max_s": max(wall), "median_cpu_s": statistics.median(cpu)}


def run(out: TextIO | None = None, sizes: tuple[int, ...] = SIZES) -> list[dict[str, Any]]:
    """Benchmark the planner step for each m in ``sizes``; print and return JSON records."""
    out = out or sys.stdout
    records = []
    for m in sizes:
        lm = Landmarks.of(*_scene(m))
        for scene, name in (("open", "planner_step"), ("crowded", "planner_step_crowded")):
            params, space, others = _setup(scene)
            times, cpu, avoiding, pc, vc = _trajectory(lm, params, space, others)
            rec = {"bench": name, "m": m, **_stats(times, cpu), "steps": len(times),
                   "steps_deflected_by_avoidance": avoiding, "obstacles": 10}
            records.append(rec)
            _emit(out, rec)
        reps = max(5, min(100, 100_000 // m))
        times, cpu = [], []
        for _ in range(reps):
            _timed(partial(plan_step, pc, vc, lm, None, 2.0, params, space, others), times, cpu)
        rec = {"bench": "planner_step_converged", "m": m, **_stats(times, cpu), "reps": reps}
        records.append(rec)
        _emit(out, rec)
    rng = np.random.default_rng(1)
    w = rng.normal(size=(10, 3))
    w /= np.linalg.norm(w, axis=1)[:, None]
    lam = -rng.uniform(0.0, 1.0, 10)
    p_opt = -w.sum(axis=0) / np.linalg.norm(w.sum(axis=0))  # infeasible: full enumeration
    times = time_calls(lambda: safe_direction(p_opt, w, lam), 500)
    rec = {"bench": "safe_direction", "obstacles": 10, "median_s": statistics.median(times)}
    records.append(rec)
    _emit(out, rec)
    q, u = _scene(1_000)
    p, v = np.array([0.3, 2.5, 1.5]), np.array([1.0, 0.0, 0.0])
    loop = time_calls(lambda: _loop_vision_gradients(p, v, q, u, 2.0), 5)
    vec = time_calls(lambda: gradients(p, v, q, u, 2.0), 50)
    rec = {"bench": "vision_gradients_loop", "m": 1_000, "median_s": statistics.median(loop)}
    records.append(rec)
    _emit(out, rec)
    rec = {"bench": "vision_gradients_vectorised", "m": 1_000, "median_s": statistics.median(vec)}
    records.append(rec)
    _emit(out, rec)
    return records


if __name__ == "__main__":
    run()
