"""One object per autopilot flavour, from the settings to the simulated vehicles
(docs/autopilots.md): every registered flavour implements the whole contract, on the agent's
side (:class:`agent.wire.mavlink.Autopilot`) and the simulator's
(:class:`groundstation.vehicle.flavours.base.SimFlavour`, its mission classes); and a third
flavour, defined here and registered without editing any library file, is accepted by the
flight settings and flown by the simulated vehicle, over raw MAVLink and through the real
driver."""

from __future__ import annotations

import inspect
from collections.abc import Iterator
from typing import Any, ClassVar

import numpy as np
import pytest

from agent.config.flight import parse_flight
from agent.config.scenario import ScenarioError
from agent.flight import qgc_plan
from agent.flight.driver_types import DriverConfig
from agent.flight.hover import hover_seed_from_params
from agent.flight.preflight import preflight_problems
from agent.wire.mavlink import (
    ARDUCOPTER_MODES,
    ArduPilot,
    Autopilot,
    flavour,
    flavour_names,
    flavour_of_heartbeat,
    mavlink,
    register,
    unregister,
)
from bench.bench_flight import FlightRig
from groundstation.vehicle.flavours import SIM_FLAVOURS, SimArduPilot, sim_class_of, sim_flavour
from groundstation.vehicle.flavours.base import SimFlavour
from groundstation.vehicle.mission_exec import MissionExec
from groundstation.vehicle.mission_fly import Flight
from groundstation.vehicle.params import VehicleParams
from tests.sim_vehicle_helpers import hello
from tests.vehicle_harness import Harness

M = mavlink
OFFSET = 100


class Renumbered(ArduPilot):
    """A third autopilot: ArduCopter's behaviour, every mode number moved up by 100 and a
    HEARTBEAT id of its own (what a fork or a firmware of another make looks like)."""

    name = "renumbered"
    mav_autopilot = int(M.MAV_AUTOPILOT_GENERIC)
    modes: ClassVar = {number + OFFSET: mode for number, mode in ARDUCOPTER_MODES.items()}


@pytest.fixture
def renumbered() -> Iterator[Autopilot]:
    """The third flavour, registered for the test only."""
    third = register(Renumbered())
    try:
        yield third
    finally:
        unregister(third.name)


# -- the contract -------------------------------------------------------------------------

def _members(contract: type) -> list[str]:
    """A contract's attributes (annotated in its body) and public methods."""
    names = list(inspect.get_annotations(contract))
    return names + [n for n, v in vars(contract).items()
                    if callable(v) and not n.startswith("_") and n not in names]


class _Steps:
    """A supervisor that records what a flavour's engage and land ask of it."""

    set_guid_options = True
    prestream_s = 0.5

    def __init__(self) -> None:
        self.calls: list[tuple[Any, ...]] = []

    def set_mode(self, main: int, sub: int = 0) -> None:
        self.calls.append(("set_mode", main, sub))

    def ensure_param_bits(self, name: str, bits: int) -> None:
        self.calls.append(("param", name, bits))

    def wait_streaming(self, seconds: float) -> None:
        self.calls.append(("stream", seconds))


def agent_gaps(fl: Any) -> list[str]:
    """What the agent-side flavour ``fl`` lacks of :class:`Autopilot`, or gets wrong: every
    member present, its modes consistent, engage ending in its control mode, land in its
    landing mode."""
    gaps = [f"{fl.name}: no {n}" for n in _members(Autopilot) if not hasattr(fl, n)]
    if gaps:
        return gaps
    control = fl.custom_mode(fl.control_mode)
    params, shown = fl.set_mode_params(*fl.mode_args(fl.control_mode))
    checks = {
        "control_modes": fl.control_modes() == [control] and shown == control,
        "in_control_mode": fl.in_control_mode(control)
        and not fl.in_control_mode(fl.custom_mode(fl.land_mode)),
        "mode_name": fl.mode_name(control) == fl.control_mode
        and fl.mode_name(fl.custom_mode(fl.land_mode)) == fl.land_mode,
        "mode_key": fl.mode_key(control) == fl.mode_key(shown),
        "set_mode_params": params[0] == M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
        "registry": flavour(fl.name) is fl,
    }
    engage, land = _Steps(), _Steps()
    fl.engage(engage)
    fl.land(land)
    checks["engage"] = engage.calls[-1] == ("set_mode", *fl.mode_args(fl.control_mode))
    checks["land"] = land.calls == [("set_mode", *fl.mode_args(fl.land_mode))]
    return gaps + [f"{fl.name}: {n}" for n, ok in checks.items() if not ok]


def sim_gaps(name: str) -> list[str]:
    """What the simulated flavour of ``name`` lacks of :class:`SimFlavour` (every abstract
    method implemented, every attribute set, its mission and flight classes complete) or
    gets wrong (its named modes among the modes it takes)."""
    cls = sim_class_of(flavour(name))
    gaps = [f"{name}: abstract {m}" for m in sorted(getattr(cls, "__abstractmethods__", ()))]
    if gaps:
        return gaps
    fl = sim_flavour(name)
    gaps = [f"{name}: no {n}" for n in _members(SimFlavour) if not hasattr(fl, n)]
    mission = fl.mission_class
    for part, base in ((mission, MissionExec), (getattr(mission, "flight", None), Flight)):
        if not (inspect.isclass(part) and issubclass(part, base)) or inspect.isabstract(part):
            gaps.append(f"{name}: {base.__name__} incomplete: {part}")
        else:
            gaps += [f"{name}: {part.__name__}.{n} unset" for n in base.__annotations__
                     if not hasattr(part, n)]
    if gaps:
        return gaps
    named = {fl.initial_mode, fl.land_mode, fl.rtl_mode, fl.hold_mode, fl.loiter_mode,
             fl.mission_mode, *fl.kinds, *fl.needs_position, *fl.stream_gated_modes,
             *fl.position_guided_modes}
    return [f"{name}: mode {m} not taken" for m in sorted(named - fl.known_modes)]


@pytest.mark.parametrize("name", flavour_names())
def test_every_registered_flavour_implements_the_whole_contract(name: str) -> None:
    assert agent_gaps(flavour(name)) == []
    assert sim_gaps(name) == []


def test_the_contract_checks_find_what_a_flavour_lacks(monkeypatch: pytest.MonkeyPatch) -> None:
    """A flavour without a landing mode, and a simulated one without its takeoff, are
    reported (so the test above can fail)."""

    class NoLanding(ArduPilot):
        name = "no-landing"
        land_mode = "NO_SUCH_MODE"

    class NoTakeoff(SimArduPilot):
        takeoff = SimFlavour.takeoff  # the abstract method again

    third = register(NoLanding())
    try:
        with pytest.raises(ValueError, match="no mode 'NO_SUCH_MODE'"):
            agent_gaps(third)
        monkeypatch.setitem(SIM_FLAVOURS, NoLanding, NoTakeoff)
        assert sim_gaps("no-landing") == ["no-landing: abstract takeoff"]
    finally:
        unregister(third.name)


# -- a third flavour ------------------------------------------------------------------------

def test_a_third_flavour_is_accepted_wherever_a_flavour_is_named(renumbered: Autopilot
                                                                 ) -> None:
    assert agent_gaps(renumbered) == [] and sim_gaps("renumbered") == []
    text = '[flight]\nautopilot = "renumbered"\n'
    assert parse_flight(text, "third.flight.toml").autopilot == "renumbered"
    assert DriverConfig(autopilot="renumbered").autopilot == "renumbered"
    assert VehicleParams(autopilot="renumbered").autopilot == "renumbered"
    assert flavour_of_heartbeat(M.MAV_AUTOPILOT_GENERIC) is renumbered
    assert qgc_plan.AUTOPILOTS["renumbered"] == M.MAV_AUTOPILOT_GENERIC
    assert hover_seed_from_params("renumbered", {"MOT_THST_HOVER": 0.3}, 0.5) == 0.3
    # ArduPilot's parameters, so ArduPilot's pre-flight rules (here: nothing read yet)
    assert {p.param for p in preflight_problems("renumbered", {})} >= {"VISO_TYPE",
                                                                       "GUID_OPTIONS"}
    assert renumbered.mode_name(OFFSET + 20) == "GUIDED_NOGPS"
    assert renumbered.set_mode_params(*renumbered.mode_args("LAND"))[1] == OFFSET + 9


def test_an_unknown_flavour_is_one_line_naming_the_known_ones() -> None:
    with pytest.raises(ScenarioError, match=r"flight\.autopilot: autopilot must be one of "
                       r"ardupilot, px4, got 'renumbered'$"):
        parse_flight('[flight]\nautopilot = "renumbered"\n', "third.flight.toml")
    with pytest.raises(ValueError, match="one of ardupilot, px4, got 'renumbered'"):
        VehicleParams(autopilot="renumbered")
    with pytest.raises(ValueError, match="is registered already"):
        register(ArduPilot())


def test_the_simulated_vehicle_runs_a_third_flavour(renumbered: Autopilot) -> None:
    """Over raw MAVLink: its HEARTBEAT id and mode numbers, ArduCopter's numbers refused, a
    GUIDED takeoff to 2 m and a LAND that disarms on the ground."""
    with hello(Harness(VehicleParams(autopilot="renumbered", indoor=True))) as h:
        assert isinstance(h.quad.flavour, SimArduPilot) and h.quad.flavour.name == "renumbered"
        hb = h.wait_for("HEARTBEAT")
        assert hb is not None and hb.autopilot == M.MAV_AUTOPILOT_GENERIC
        assert hb.custom_mode == OFFSET + 0  # STABILIZE
        h.every = h.vision
        h.run(0.3)
        assert h.set_mode(4) == M.MAV_RESULT_FAILED  # ArduCopter's GUIDED: not one of its modes
        assert h.set_mode(OFFSET + 4) == M.MAV_RESULT_ACCEPTED
        assert h.wait_for("HEARTBEAT", lambda m: m.custom_mode == OFFSET + 4) is not None
        assert h.arm() == M.MAV_RESULT_ACCEPTED
        assert h.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 2.0) == M.MAV_RESULT_ACCEPTED
        h.run(5.0)
        assert h.altitude() == pytest.approx(2.0, abs=0.2)
        assert h.command(M.MAV_CMD_NAV_LAND) == M.MAV_RESULT_ACCEPTED
        assert h.wait_for("HEARTBEAT", lambda m: m.custom_mode == OFFSET + 9) is not None
        h.run(8.0)
        assert not h.quad.armed and h.quad.log.has("landed")


def test_the_driver_flies_a_third_flavour_on_the_simulated_vehicle(renumbered: Autopilot
                                                                   ) -> None:
    """The real driver (engage: GUID_OPTIONS, then its GUIDED_NOGPS; land: its LAND), the
    flavour found from the HEARTBEAT, on the simulated vehicle at 3× real time."""
    with FlightRig(VehicleParams(autopilot="renumbered")) as rig:
        assert rig.driver.vehicle.autopilot == M.MAV_AUTOPILOT_GENERIC
        rig.take_off(0.8)
        rig.run_for(4.0)
        assert rig.quad.mode == OFFSET + 20 and rig.driver.phase == "flying"
        assert rig.quad.params_table["GUID_OPTIONS"] == 8
        assert float(rig.fleet.p[0, 2]) == pytest.approx(-0.8, abs=0.15)  # NED
        assert rig.driver.land(timeout_s=15.0)
        assert rig.quad.mode == OFFSET + 9 and not rig.quad.armed
        assert np.isfinite(rig.fleet.p[0]).all()
