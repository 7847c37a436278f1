"""Shared helpers of the agent/protocol tests: scenario builders and a planner stand-in."""

from __future__ import annotations

import random

import numpy as np

from agent.config.scenario import Scenario, load_scenario, parse_scenario
from agent.runtime.agent import AgentRuntime, MotionFn
from tests.conftest import ROOT


def thesis(name: str) -> Scenario:
    """A scenario of ``scenarios/``."""
    return load_scenario(ROOT / "scenarios" / f"{name}.toml")


def random_scene_toml(n_agents: int, n_landmarks: int, seed: int, *, dims: int = 2,
                      half: float = 6.0, duration: float = 120.0) -> str:
    """TOML text of a random scene: landmarks on a circle (2-D) or sphere (3-D) of radius
    ``half``/2 facing outwards, agents spread around it, landmarks dealt round-robin."""
    rng = np.random.default_rng(seed)
    lines = [f'name = "random_{n_agents}_{n_landmarks}_{seed}"', f"dims = {dims}",
             f"seed = {seed}", "d_opt = 1.0", f"duration = {duration}", "",
             "[space]", f"lo = {[-half] * dims}", f"hi = {[half] * dims}", "",
             "[planner]", "dt = 0.1", 'avoidance = "smooth"', "r_s = 0.6", "d_w = 0.3", ""]
    r = half / 2
    for k in range(n_landmarks):
        if dims == 2:
            a = 2 * np.pi * k / n_landmarks
            n = [float(np.cos(a)), float(np.sin(a))]
        else:
            n = rng.normal(size=3)
            n = list(map(float, n / np.linalg.norm(n)))
        pos = [float(r * x) for x in n]
        lines += ["[[landmarks]]", f"id = {k + 1}", f"position = {pos}", f"normal = {n}", ""]
    for i in range(n_agents):
        a = 2 * np.pi * i / n_agents + 0.1
        rad = half * 0.85
        pos = [rad * np.cos(a), rad * np.sin(a)] + ([0.3 * rng.uniform(-1, 1) * rad]
                                                    if dims == 3 else [])
        own = list(range(i + 1, n_landmarks + 1, n_agents))
        lines += ["[[agents]]", f'id = "N{i}"', f"position = {[float(x) for x in pos]}",
                  f"yaw = {float(a + np.pi)}", f"landmarks = {own}", ""]
    return "\n".join(lines)


def random_scene(n_agents: int, n_landmarks: int, seed: int, **kw: object) -> Scenario:
    """:func:`random_scene_toml` parsed."""
    return parse_scenario(random_scene_toml(n_agents, n_landmarks, seed, **kw),  # type: ignore[arg-type]
                          f"<random {seed}>")


def fixed_motion(seed: int, max_ticks: int = 4):
    """A planner stand-in: the agent never moves and 'converges' after 0..max_ticks ticks of
    optimising. Algorithm 7 then runs on fixed poses (fast protocol stress)."""

    def factory(aid: str) -> MotionFn:
        rng = random.Random(f"{seed}:{aid}")
        left: list[int | None] = [None]

        def motion(_rt: AgentRuntime) -> bool:
            if left[0] is None:
                left[0] = rng.randint(0, max_ticks)
            if left[0] <= 0:
                left[0] = None
                return True
            left[0] -= 1
            return False

        return motion

    return factory
