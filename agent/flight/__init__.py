"""The flight side (thesis chapter 6.1) as a vehicle adapter.

Pure maths (no I/O, no clocks): :mod:`~agent.flight.frames` (ENU/NED, FLU/FRD),
:mod:`~agent.flight.attitude` (force → attitude and thrust), :mod:`~agent.flight.controllers`
(speed, position and angle loops of figures 6.1-6.2), :mod:`~agent.flight.hover` (online
hover-thrust estimate), :mod:`~agent.flight.monitor` (is the vehicle still ours?),
:mod:`~agent.flight.preflight` (autopilot parameters that must be set, fence rules),
:mod:`~agent.flight.flavours` (one class per autopilot: modes, engage, land),
:mod:`~agent.flight.geodetic` (WGS-84: world ENU ↔ latitude, longitude, altitude; an EKF's
local frame → the mission's world frame),
:mod:`~agent.flight.refly` and :mod:`~agent.flight.qgc_plan` (an inspection's captures as
QGroundControl plans to fly again).

Adapters: :mod:`~agent.flight.mavlink_driver` (one vehicle: the parts below on one link),
:mod:`~agent.flight.link` (connection, HEARTBEAT, routing, commands),
:mod:`~agent.flight.params` (parameter protocol), :mod:`~agent.flight.supervisor` (modes,
arming, engage/land, the vehicle monitor), :mod:`~agent.flight.streamer` (set-points,
failsafes, guards), :mod:`~agent.flight.autopilot_check` (the autopilot's parameters read
before take-off: pre-flight check, hover-thrust seed), :mod:`~agent.flight.vehicle_pose` (the
flown vehicle as the runtime's pose source, fed by mocap over Zenoh). Field clients on the
same link, opened together by :mod:`~agent.flight.field`: :mod:`~agent.flight.camera`,
:mod:`~agent.flight.gimbal`, :mod:`~agent.flight.fence` (with
:mod:`~agent.flight.mission_protocol`), :mod:`~agent.flight.battery`,
:mod:`~agent.flight.autopilot_pose` (pose from the autopilot). The flying agent that puts
them together is :mod:`agent.runners.flying`.
"""
