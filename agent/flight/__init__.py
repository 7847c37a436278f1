"""Flight side of viscover (thesis chapter 6): frames, controllers, force-to-attitude,
the MAVLink driver and the MAVLink-backed pose source.

Pure maths (no I/O): :mod:`agent.flight.frames`, :mod:`agent.flight.attitude`,
:mod:`agent.flight.controllers`. Wire messages and keys: :mod:`agent.wire.ground`.
I/O at the edges: :mod:`agent.wire.mavlink` (pymavlink for MAVLink 2),
:mod:`agent.flight.mavlink_driver`, :mod:`agent.flight.pose_source`, and
:mod:`agent.flight.fly` (one drone as a process: take off, hold, land on SIGINT/SIGTERM).
"""
