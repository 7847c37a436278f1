"""viscover's drone side, in layers. A module may import from its own package and from the
layers below it, never from a layer above (``tests/test_layers.py`` walks every import):

====  ====================  ==============================================================
rank  package               what it holds
====  ====================  ==============================================================
0     ``agent.core``        the thesis in pure numpy: vision (ch. 3), avoidance, line search,
                            planner (ch. 4), trading (Alg. 7), orientation, landmark
                            generators, homing; no I/O, no clocks, no threads
0     ``agent.clock``       the one :class:`~agent.clock.Clock` contract, wall and manual clocks
0     ``agent.errors``      :class:`~agent.errors.UsageError` and the exit statuses
1     ``agent.wire``        the wire contract: every message that crosses a process boundary
                            (peer messages, ground-station messages), key expressions, the
                            codec, MAVLink constants
1     ``agent.strategy``    per-drone decisions of a strategy (inspection tours, re-splits)
                            as pure functions, and the registry of strategies by name with
                            the moves each makes
2     ``agent.protocol``    the trade protocol as a pure state machine and its journal records
2     ``agent.config``      scenario and flight-settings files (TOML, validated by msgspec)
2     ``agent.structure``   structures from meshes: landmarks, occlusion, clearance, the
                            capture table of an inspection
3     ``agent.net``         Zenoh and in-memory transports, fault injection, router (and the
                            fence record it keeps), clock sync
3     ``agent.storage``     the fsynced journal; the MCAP recording's channels and colours;
                            the mission events as typed msgspec Structs
3     ``agent.world``       a scenario made concrete: the structure resolved, per-agent planner
                            inputs, the viewpoint environment, transits, inspection tables
4     ``agent.flight``      chapter 6.1: frames, force → attitude, controllers (pure); the
                            MAVLink driver and the flown vehicle as a pose source (adapters)
5     ``agent.runtime``     the agent core (``step(event) -> effects``: trade client and
                            server, membership, completion, adoption, the strategy's moves;
                            time and the vehicle only as events, every action an effect; no
                            clock, lock or I/O) and the runtime that carries its effects out
5     ``agent.sim``         the lockstep simulator on virtual time (chapter 5's thesis
                            strategy, inspection), every engine's result, report and replay;
                            neither it nor the runtime imports the other
6     ``agent.mission``     mission tooling: observer and invariants, watch and status,
                            recorder, launcher, operator commands
7     ``agent.runners``     process runners: the kinematic agent process, the flying agent
7     ``agent.testing``     harnesses: a whole mission in memory on virtual time, and the
                            agents' engine of ``viscover simulate`` (its default)
8     ``agent.commands``    the ``viscover`` subcommands and the CLI kit
9     ``agent.cli``         the ``viscover`` entry point (the only module that may import
                            :mod:`groundstation`)
====  ====================  ==============================================================

:mod:`groundstation` (mocap, simulated vehicles, the clock master) sits above
``agent.commands`` and may import any of these; nothing in ``agent`` imports it.
"""
