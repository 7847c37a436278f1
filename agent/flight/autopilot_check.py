"""Read the autopilot before flying it: its hover thrust (the seed of the hover-thrust
estimate) and the parameters the pre-flight rules need (:mod:`agent.flight.preflight`), over
the MAVLink parameter protocol through a connected :class:`~agent.flight.mavlink_driver.
MavlinkDriver`. Used by ``viscover preflight`` and by the flying agent before every take-off.
"""

from __future__ import annotations

from dataclasses import dataclass

from agent.flight.hover import HOVER_PARAM, HoverThrustEstimator, hover_seed_from_params
from agent.flight.mavlink_driver import MavlinkDriver
from agent.flight.preflight import PARAMETER_TABLE, Problem, preflight_problems, problem_line
from agent.wire.mavlink import mavlink

#: HEARTBEAT.autopilot → our flavour name.
FLAVOUR_OF = {mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA: "ardupilot", mavlink.MAV_AUTOPILOT_PX4: "px4"}


def parameters_to_read(autopilot: str) -> list[str]:
    """Every parameter the checks of flavour ``autopilot`` read: the pre-flight rules' and the
    hover thrust's (MOT_THST_HOVER / MPC_THR_HOVER)."""
    names = [r.param for r in PARAMETER_TABLE if r.flavour == autopilot]
    return [*names, HOVER_PARAM[autopilot]]


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


def check_autopilot(driver: MavlinkDriver, default_hover: float) -> AutopilotReport:
    """Read the parameters of :func:`parameters_to_read` from the vehicle (the driver must
    have heard its HEARTBEAT) and apply the pre-flight rules; ``default_hover`` seeds the
    hover thrust when the autopilot does not report one."""
    autopilot = driver.cfg.autopilot
    params = driver.read_params(parameters_to_read(autopilot))
    name = HOVER_PARAM[autopilot]
    seed = hover_seed_from_params(autopilot, params, default_hover)
    return AutopilotReport(autopilot, driver.target_system, params,
                           preflight_problems(autopilot, params), seed,
                           name if name in params else "default")


def seed_hover_thrust(driver: MavlinkDriver, report: AutopilotReport) -> None:
    """Give the driver's controller the autopilot's hover thrust and an online estimator
    seeded with it (:class:`~agent.flight.hover.HoverThrustEstimator`)."""
    ctl = driver.controller
    ctl.set_hover_thrust(report.hover_seed)
    ctl.hover = HoverThrustEstimator(ctl.model.hover_thrust)
