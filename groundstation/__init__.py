"""The ground station: motion capture (simulated or real), the mission's landmark set and the
shared simulation clock on Zenoh. It may import any layer of :mod:`agent`; nothing in
:mod:`agent` but the ``viscover`` entry point imports it.

Modules: :mod:`groundstation.vehicle` (simulated quadrotors that speak MAVLink 2 like
ArduPilot's and PX4's SITL: pure dynamics, autopilot emulation, the fleet runner),
:mod:`groundstation.mocap` (pose sources: simulator, ``motioncapture``),
:mod:`groundstation.station` (the publishing loop), :mod:`groundstation.cli`
(``viscover groundstation``). Flight settings (``<scenario>.flight.toml``) are read by
:mod:`agent.config.flight`; the clock is published by :mod:`agent.net.clocksync`.
"""
