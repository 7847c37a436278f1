"""Shared helpers of the agent/protocol tests: scenario builders and a planner stand-in."""

from __future__ import annotations

import random
from collections.abc import Callable

import numpy as np

from agent.config.parse import load_scenario, parse_scenario
from agent.config.scenario import Scenario
from agent.runtime.moves.revert import Revert
from agent.runtime.shell.runtime import AgentRuntime, MotionFn
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
            g = rng.normal(size=3)
            n = list(map(float, g / np.linalg.norm(g)))
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


def scenario_toml(sc: Scenario, **top: object) -> str:
    """TOML text of scenario ``sc`` (3-D, explicit landmarks; floats written exactly), with
    top-level fields ``top`` (e.g. ``strategy="potential"``) added."""
    prm = sc.params
    lines = [f"{k} = {v!r}" if not isinstance(v, str) else f'{k} = "{v}"'
             for k, v in top.items()]
    lines += [f'name = "{sc.name}"', "dims = 3", f"seed = {sc.seed}", f"d_opt = {sc.d_opt!r}",
              f"duration = {sc.duration!r}", "", "[space]",
              f"lo = {[float(x) for x in sc.space.lo]}", f"hi = {[float(x) for x in sc.space.hi]}",
              "", "[planner]", f"dt = {prm.dt!r}", f"p_lim = {prm.p_lim!r}",
              f"p_min = {prm.p_min!r}", f"w_lim = {float(prm.w_lim)!r}",
              f"w_min = {float(prm.w_min)!r}", f"tau = {prm.tau!r}", f"beta = {prm.beta!r}",
              f'avoidance = "{prm.avoidance}"', f"r_s = {prm.r_s!r}", f"d_w = {prm.d_w!r}", ""]
    for lid, q, u in zip(sc.landmark_ids, sc.q, sc.u, strict=True):
        lines += ["[[landmarks]]", f"id = {lid}", f"position = {[float(x) for x in q]}",
                  f"normal = {[float(x) for x in u]}", ""]
    ids = np.asarray(sc.landmark_ids)
    for a in sc.agents:
        lines += ["[[agents]]", f'id = "{a.id}"', f"position = {[float(x) for x in a.p0]}",
                  f"direction = {[float(x) for x in a.v0]}",
                  f"landmarks = {ids[a.landmarks].tolist()}", ""]
    return "\n".join(lines)


def random_scene(n_agents: int, n_landmarks: int, seed: int, *, dims: int = 2,
                 half: float = 6.0, duration: float = 120.0) -> Scenario:
    """:func:`random_scene_toml` parsed."""
    return parse_scenario(random_scene_toml(n_agents, n_landmarks, seed, dims=dims, half=half,
                                            duration=duration), f"<random {seed}>")


def fixed_motion(seed: int, max_ticks: int = 4) -> Callable[[str], MotionFn]:
    """A planner stand-in: the agent never moves and 'converges' after 0..max_ticks ticks of
    optimising. Algorithm 7 then runs on fixed poses (fast protocol stress)."""

    def factory(aid: str) -> MotionFn:
        rng = random.Random(f"{seed}:{aid}")
        left: list[int | None] = [None]

        def motion() -> bool:
            ticks = left[0]
            if ticks is None:
                ticks = rng.randint(0, max_ticks)
            if ticks <= 0:
                left[0] = None
                return True
            left[0] = ticks - 1
            return False

        return motion

    return factory


def revert_of(rt: AgentRuntime) -> Revert:
    """The revert move of an agent whose strategy registers it ("potential")."""
    revert = rt.core.driver.find(Revert)
    assert revert is not None, f"agent {rt.id}: its strategy makes no revert"
    return revert
