"""viscover ground station (issue 4): motion capture (simulated or real) and the shared
simulation clock on Zenoh.

Modules: :mod:`groundstation.sim_quad` (simulated quadrotors speaking MAVLink 2),
:mod:`groundstation.mocap` (pose sources: simulator, ``motioncapture``), :mod:`groundstation.
station` (publishing loop), :mod:`groundstation.clock` (simulation clock),
:mod:`agent.config.flight` (``<scenario>.flight.toml``), :mod:`groundstation.cli_commands`
(``viscover groundstation``).
"""
