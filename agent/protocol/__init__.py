"""The trade protocol as a pure state machine (:mod:`agent.protocol.machine`) and its journal
records (:mod:`agent.protocol.records`). The messages it exchanges are in
:mod:`agent.wire.peer`; *what* to trade (Algorithm 7) is decided in
:mod:`agent.core.trading`. How an inspection mission ended (complete, or what was given up
and why) is :mod:`agent.protocol.inspection_end`, the one function every report of it uses."""
