"""Simulated quadrotors that speak MAVLink 2 over UDP, as ArduPilot's and PX4's SITL do.

* :mod:`~groundstation.vehicle.dynamics`: pure, vectorised vehicle model (``step``).
* :mod:`~groundstation.vehicle.params`: :class:`VehicleParams` and the autopilot parameters.
* :mod:`~groundstation.vehicle.control`: the autopilot's per-mode controllers.
* :mod:`~groundstation.vehicle.autopilot`: the MAVLink autopilot (ArduCopter / PX4 flavour).
* :mod:`~groundstation.vehicle.flavours`: what each flavour does its own way, one object per
  autopilot built from the agent's flavour (``docs/autopilots.md``); the modules below apply it.
* :mod:`~groundstation.vehicle.modes`: mode rules, arming checks, NAV_TAKEOFF, SYS_STATUS health.
* :mod:`~groundstation.vehicle.conventions`: the EKF origin, geodetic positions and units.
* :mod:`~groundstation.vehicle.inbound`: addressing and parameter checks of what it receives.
* :mod:`~groundstation.vehicle.commands`: its COMMAND_LONG / COMMAND_INT handling and ACKs.
* :mod:`~groundstation.vehicle.telemetry`: streams, intervals and message encoders.
* :mod:`~groundstation.vehicle.fleet`: UDP links, the fleet loop, mocap and :class:`FleetClock`.
* :mod:`~groundstation.vehicle.mission_exec`: stored missions flown in AUTO / AUTO.MISSION,
  item by item (:mod:`.mission_fly`: the NAV item flown; :mod:`.mission_nav`: legs and
  tracking; :mod:`.mission_do`: the DO items).
* :mod:`~groundstation.vehicle.devices`: the outdoor equipment wired in: :mod:`.camera`,
  :mod:`.gimbal`, :mod:`.fence` (mission protocol, breaches), :mod:`.battery` (monitor and
  failsafes, :mod:`.failsafe`), :mod:`.ekf` (GNSS-aided estimate with noise and drift).
"""

from groundstation.vehicle.autopilot import Autopilot
from groundstation.vehicle.dynamics import FleetParams, VehicleState
from groundstation.vehicle.fleet import FleetClock, MocapSample, SimFleet
from groundstation.vehicle.params import VehicleParams

__all__ = ["Autopilot", "FleetClock", "FleetParams", "MocapSample", "SimFleet", "VehicleParams",
           "VehicleState"]
