"""Read the autopilot before flying it: its hover thrust (the seed of the hover-thrust
estimate) and the parameters the pre-flight rules need (:mod:`agent.flight.preflight`), over
the MAVLink parameter protocol through a connected :class:`~agent.flight.mavlink_driver.
MavlinkDriver`. Used by ``viscover preflight`` and by the flying agent before every take-off.
"""

from __future__ import annotations

from dataclasses import dataclass

from agent.flight.flavours import FLAVOURS, flavour
from agent.flight.hover import HoverThrustEstimator, hover_seed_from_params
from agent.flight.mavlink_driver import MavlinkDriver
from agent.flight.preflight import (
    FENCE_TABLE,
    PARAMETER_TABLE,
    Problem,
    fence_problems,
    preflight_problems,
    problem_line,
)

#: HEARTBEAT.autopilot → our flavour name.
FLAVOUR_OF = {f.mav_autopilot: name for name, f in FLAVOURS.items()}


def parameters_to_read(autopilot: str, pose: str = "mocap", fence: bool = False) -> list[str]:
    """Every parameter the checks of flavour ``autopilot`` read: the pre-flight rules' (for
    flying on ``pose`` "mocap" or "autopilot"; the fence rules' with ``fence``) and the hover
    thrust's (MOT_THST_HOVER / MPC_THR_HOVER)."""
    rules = [r for r in PARAMETER_TABLE if not r.mocap or pose == "mocap"]
    if fence:
        rules += FENCE_TABLE
    family = flavour(autopilot).param_family  # the rules of the flavour it derives from
    names = list(dict.fromkeys(r.param for r in rules if r.flavour == family))
    return [*names, flavour(autopilot).hover_param]


@dataclass(frozen=True)
class AutopilotReport:
    """What the autopilot told us: flavour, system id, the parameters read (name → value,
    decoded), the pre-flight problems, and the hover thrust seed (normalised) with where it
    came from (the parameter's name, or 'default')."""

    autopilot: str
    system: int
    params: dict[str, float]
    problems: list[Problem]
    hover_seed: float
    hover_source: str

    @property
    def fatal(self) -> list[Problem]:
        """The problems that must stop the flight."""
        return [p for p in self.problems if p.fatal]

    def refusal(self) -> str:
        """One line: why we refuse to fly, with the fix ('' when nothing is fatal)."""
        bad = self.fatal
        if not bad:
            return ""
        more = f" (and {len(bad) - 1} more: {', '.join(p.param for p in bad[1:])})" \
            if len(bad) > 1 else ""
        return f"pre-flight: {problem_line(bad[0])}{more}"

    def summary(self) -> str:
        """One line for a passed check: flavour, system, hover thrust and its source."""
        warn = [p.param for p in self.problems if not p.fatal]
        return (f"{self.autopilot} system {self.system}, hover thrust {self.hover_seed:.3f} "
                f"from {self.hover_source}" + (f", warnings: {', '.join(warn)}" if warn else ""))


def check_autopilot(driver: MavlinkDriver, default_hover: float, pose: str = "mocap",
                    fence: bool = False) -> AutopilotReport:
    """Read the parameters of :func:`parameters_to_read` from the vehicle (the driver must
    have heard its HEARTBEAT) and apply the pre-flight rules (for ``pose`` "mocap" or
    "autopilot"; the fence rules too with ``fence``); ``default_hover`` seeds the hover
    thrust when the autopilot does not report one."""
    autopilot = driver.cfg.autopilot
    params = driver.read_params(parameters_to_read(autopilot, pose, fence))
    name = flavour(autopilot).hover_param
    seed = hover_seed_from_params(autopilot, params, default_hover)
    problems = preflight_problems(autopilot, params, pose)
    if fence:
        problems += fence_problems(autopilot, params)
    return AutopilotReport(autopilot, driver.target_system, params, problems, seed,
                           name if name in params else "default")


def seed_hover_thrust(driver: MavlinkDriver, report: AutopilotReport) -> None:
    """Give the driver's controller the autopilot's hover thrust and an online estimator
    seeded with it (:class:`~agent.flight.hover.HoverThrustEstimator`)."""
    ctl = driver.controller
    ctl.set_hover_thrust(report.hover_seed)
    ctl.hover = HoverThrustEstimator(ctl.model.hover_thrust)
