"""The wire contract: every message that crosses a process boundary, as versioned
``msgspec.Struct`` s. :mod:`~agent.wire.peer` (what agents publish and ask each other: pose,
state, status, trades), :mod:`~agent.wire.ground` (what the ground station publishes: mocap,
its health, landmarks, the clock), :mod:`~agent.wire.keys` (Zenoh key expressions),
:mod:`~agent.wire.codec` (decode, validate, reject and count) and
:mod:`~agent.wire.mavlink` (pymavlink for MAVLink 2 and the autopilots' mode numbers)."""
