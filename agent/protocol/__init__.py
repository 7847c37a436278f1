"""The trade protocol as a pure state machine (:mod:`agent.protocol.machine`) and its journal
records (:mod:`agent.protocol.records`). The messages it exchanges are in
:mod:`agent.wire.peer`; *what* to trade (Algorithm 7) is decided in
:mod:`agent.core.trading`."""
