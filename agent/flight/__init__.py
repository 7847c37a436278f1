"""The flight side (thesis chapter 6.1) as a vehicle adapter.

Pure maths (no I/O, no clocks): :mod:`~agent.flight.frames` (ENU/NED, FLU/FRD),
:mod:`~agent.flight.attitude` (force → attitude and thrust), :mod:`~agent.flight.controllers`
(speed, position and angle loops of figures 6.1-6.2), :mod:`~agent.flight.hover` (online
hover-thrust estimate), :mod:`~agent.flight.monitor` (is the vehicle still ours?),
:mod:`~agent.flight.preflight` (autopilot parameters that must be set),
:mod:`~agent.flight.geodetic` (WGS-84: world ENU ↔ latitude, longitude, altitude),
:mod:`~agent.flight.refly` and :mod:`~agent.flight.qgc_plan` (an inspection's captures as
QGroundControl plans to fly again).

Adapters: :mod:`~agent.flight.mavlink_driver` (HEARTBEAT, mode, arming, set-point stream and
failsafes over MAVLink 2; the vehicle monitor's inputs), :mod:`~agent.flight.autopilot_check`
(the autopilot's parameters read before take-off: pre-flight check, hover-thrust seed) and
:mod:`~agent.flight.vehicle_pose` (the flown vehicle as the runtime's pose source, fed by
mocap over Zenoh). The flying agent that puts them together is
:mod:`agent.runners.flying`.
"""
