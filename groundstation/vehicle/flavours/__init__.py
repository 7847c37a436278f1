"""The simulated vehicle's autopilot flavours: one :class:`~.base.SimFlavour` per autopilot,
built from the agent's flavour object (:mod:`agent.wire.mavlink`), holding every choice the
vehicle makes differently per autopilot (:mod:`.base` is the contract; :mod:`.ardupilot` and
:mod:`.px4`, with their missions in :mod:`.ardupilot_mission` and :mod:`.px4_mission`).

:func:`sim_flavour` finds the simulated behaviour of an agent flavour by its class: the
class's own, else that of the nearest base class that has one (:data:`SIM_FLAVOURS`), so a
flavour derived from :class:`~agent.wire.mavlink.ArduPilot` (other mode numbers, say) is
simulated as ArduCopter with its own numbers; :func:`register_sim` adds a new behaviour.
``docs/autopilots.md``: how to add a flavour.
"""

from __future__ import annotations

from agent.wire.mavlink import PX4, ArduPilot, Autopilot, flavour
from groundstation.vehicle.flavours.ardupilot import SimArduPilot
from groundstation.vehicle.flavours.base import SimFlavour
from groundstation.vehicle.flavours.px4 import SimPX4

#: Agent flavour class → the simulated behaviour of its flavours.
SIM_FLAVOURS: dict[type, type[SimFlavour]] = {ArduPilot: SimArduPilot, PX4: SimPX4}


def register_sim(autopilot_class: type, sim_class: type[SimFlavour]) -> None:
    """Simulate the flavours of ``autopilot_class`` (and of classes derived from it that
    have none of their own) with ``sim_class``."""
    SIM_FLAVOURS[autopilot_class] = sim_class


def sim_class_of(autopilot: Autopilot) -> type[SimFlavour]:
    """The simulated behaviour of the agent flavour ``autopilot`` (ValueError if none)."""
    for cls in type(autopilot).__mro__:
        found = SIM_FLAVOURS.get(cls)
        if found is not None:
            return found
    raise ValueError(f"autopilot {autopilot.name!r} has no simulated behaviour: derive its "
                     "class from a simulated one or register_sim() one")


def sim_flavour(name: str) -> SimFlavour:
    """A new :class:`~.base.SimFlavour` of the registered flavour called ``name`` (ValueError,
    one line, for an unknown name or one without a simulated behaviour)."""
    autopilot = flavour(name)
    return sim_class_of(autopilot)(autopilot)


__all__ = ["SIM_FLAVOURS", "SimArduPilot", "SimFlavour", "SimPX4", "register_sim",
           "sim_class_of", "sim_flavour"]
