"""Traffic per drone at 5, 10 and 20 drones: messages and bytes per mission second, sent and
received, by message kind.

What is measured: whole missions of the agents' own code (:class:`agent.testing.memsim.
MemoryMission`, every agent a :class:`~agent.runtime.shell.runtime.AgentRuntime`) on an
in-memory network that counts, per drone, what its Zenoh session would put on and take off
its link: every publication it sends (pose, state, status, ...) and every one delivered to it
(once per drone however many of its subscriptions match, not its own), every trade query it
sends or answers and every reply. The payloads are the very msgpack bytes the Zenoh transport
sends; the in-memory network delivers exactly what a Zenoh router would deliver (every
publication to every matching subscriber, each query to one queryable). Not counted: Zenoh's
framing (a few bytes a message: key expressions travel as declared ids), keep-alives (4 per
lease per link, i.e. 4 small messages a second on a 1 s lease) and liveliness declarations.

Why in memory rather than 20 agent processes on a router: on this shared 2-core machine 20
processes run behind real time, so their publication rates (and hence the per-second numbers)
would measure the CPU, not the protocol; on virtual time the rates are the protocol's, exact
and repeatable (a seeded mission). :func:`bench_zenoh` checks the sent side against real
processes on a real router at 5 drones.

The scene (:func:`bench.bench_trade.swarm_scene_toml`) keeps the landmarks per drone fixed
(``PER_DRONE``), so a state's landmark set does not grow with the team: what grows is what
depends on the team (per-peer lists and maps) and the number of publishers heard. Two series:
``radius_m`` growing with the team (8 m at 5 drones, 16 at 10, 32 at 20: the drones stand as
far apart at every size, as a team sized to its structure does; the goal: what a drone
receives does not grow linearly with the team) and 8 m at every size (every drone a
neighbour of every other: the pose streams a drone hears then grow with the team).

Rows ``traffic_per_drone`` (one per team size, ``network`` "memory"; and the check,
``network`` "zenoh"); run ``python -m bench.bench_traffic [--sizes 5,10,20] [--no-zenoh]
[--all-partners]`` (``--all-partners``: states naming every partner, as before
:data:`~agent.wire.peer.PARTNERS_PUBLISHED`: the "before" rows).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import statistics
import sys
import tempfile
import time
from collections import Counter, defaultdict
from collections.abc import Iterator
from typing import Any, TextIO

from agent.config.parse import parse_scenario
from agent.net.memory import MemoryNetwork, MemoryTransport, intersects
from agent.runtime.core import published
from agent.runtime.core.shared import AgentConfig
from agent.testing.memsim import MemoryMission
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.peer import PARTNERS_PUBLISHED, AgentState, Publication
from bench.bench_trade import swarm_scene_toml

#: Landmarks per drone in the scene (the team's share stays the same at every size).
PER_DRONE = 10
#: team size at which the spread scene's circle has its 8 m radius (it grows with the team)
SPREAD = 5
SIZES = (5, 10, 20)


class CountingNetwork(MemoryNetwork):
    """A :class:`MemoryNetwork` that counts each node's link traffic (see the module
    docstring): ``sent[node][kind]`` and ``received[node][kind]`` as [messages, bytes]."""

    def __init__(self) -> None:
        super().__init__()
        self.sent: dict[str, dict[str, list[int]]] = defaultdict(
            lambda: defaultdict(lambda: [0, 0]))
        self.received: dict[str, dict[str, list[int]]] = defaultdict(
            lambda: defaultdict(lambda: [0, 0]))
        self.state_sizes: dict[str, list[int]] = defaultdict(list)  #: sender -> state bytes
        self.largest_state: dict[str, bytes] = {}  #: sender -> its largest state payload

    @staticmethod
    def _count(table: dict[str, dict[str, list[int]]], node: str, kind: str, n: int) -> None:
        cell = table[node][kind]
        cell[0] += 1
        cell[1] += n

    def _publish(self, sender: MemoryTransport, key: str, payload: bytes, kind: str) -> None:
        self._count(self.sent, sender.node_id, kind, len(payload))
        if kind == "state":
            self.state_sizes[sender.node_id].append(len(payload))
            if len(payload) > len(self.largest_state.get(sender.node_id, b"")):
                self.largest_state[sender.node_id] = payload
        super()._publish(sender, key, payload, kind)

    def _arrive(self, sender: str, key: str, payload: bytes, kind: str) -> None:
        nodes = {s.node.node_id for s in self._live("sub")
                 if s.active and intersects(s.keyexpr, key) and s.node.node_id != sender
                 and not self._severed(sender, s.node.node_id)}
        for node in nodes:
            self._count(self.received, node, kind, len(payload))
        super()._arrive(sender, key, payload, kind)

    def _request(self, sender: MemoryTransport, key: str, payload: bytes, timeout: float,
                 kind: str) -> bytes | None:
        target = next((q.node.node_id for q in self._live("queryable")
                       if intersects(q.keyexpr, key)
                       and not self._severed(sender.node_id, q.node.node_id)), None)
        self._count(self.sent, sender.node_id, kind, len(payload))
        if target is not None:
            self._count(self.received, target, kind, len(payload))
        reply = super()._request(sender, key, payload, timeout, kind)
        if reply is not None and target is not None:
            self._count(self.sent, target, f"{kind}.reply", len(reply))
            self._count(self.received, sender.node_id, f"{kind}.reply", len(reply))
        return reply


def _per_second(table: dict[str, dict[str, list[int]]], ids: list[str], seconds: float
                ) -> dict[str, Any]:
    """Per drone per second: mean and max over drones of messages and bytes, and the mean
    by kind."""
    msgs = [sum(c[0] for c in table[a].values()) / seconds for a in ids]
    byts = [sum(c[1] for c in table[a].values()) / seconds for a in ids]
    kinds: Counter[str] = Counter()
    kind_bytes: Counter[str] = Counter()
    for a in ids:
        for k, (n, b) in table[a].items():
            kinds[k] += n
            kind_bytes[k] += b
    scale = 1.0 / (seconds * len(ids))
    return {
        "msgs_per_s": round(statistics.mean(msgs), 2), "msgs_per_s_max": round(max(msgs), 2),
        "bytes_per_s": round(statistics.mean(byts), 1), "bytes_per_s_max": round(max(byts), 1),
        "by_kind": {k: {"msgs_per_s": round(kinds[k] * scale, 2),
                        "bytes_per_s": round(kind_bytes[k] * scale, 1)}
                    for k in sorted(kinds)},
    }


def _make_counting(m: MemoryMission) -> CountingNetwork:
    net = CountingNetwork()
    m.net = net  # the mission's clock reads m.net.now: the new network's virtual time
    return net


def bench_memory(n: int, per_drone: int = PER_DRONE, seed: int = 1,
                 max_time_s: float = 600.0, partners: int | None = None, spread: bool = True
                 ) -> dict[str, Any]:
    """One seeded mission of ``n`` drones in memory; its ``traffic_per_drone`` row.
    ``partners``: how many partners a state names instead of
    :data:`~agent.wire.peer.PARTNERS_PUBLISHED` (e.g. 1000: all of them, as before it).
    ``spread``: the circle's radius grows with the team (8 m at 5 drones, :data:`SPREAD`),
    so that the drones stand as far apart at every size, as a team sized to its structure
    does; else 8 m at every size (every drone within 22 m of every other: all neighbours)."""
    radius = 8.0 * max(1.0, n / SPREAD) if spread else 8.0
    sc = parse_scenario(swarm_scene_toml(n, n * per_drone, seed=seed, r=radius),
                        f"<swarm {n}>")
    shown = PARTNERS_PUBLISHED if partners is None else partners
    with tempfile.TemporaryDirectory(prefix="viscover-traffic-") as tmp, \
            _partners_published(shown):
        m = MemoryMission(sc, tmp, config=AgentConfig(mission="traffic", seed=seed),
                          autostart=False)
        net = _make_counting(m)
        for a in sc.agents:
            m.start(a.id)
        t0 = time.perf_counter()
        done = m.run(max_time_s)
        wall = time.perf_counter() - t0
        seconds = m.net.now
        violations = m.violations + m.final_violations()
        ids = [a.id for a in sc.agents]
        sizes = [b for a in ids for b in net.state_sizes[a]]
        peer_ids = max(_state_peer_ids(p) for p in net.largest_state.values())
        m.close()
    return {
        "bench": "traffic_per_drone", "network": "memory", "drones": n,
        "partners_published": shown, "radius_m": round(radius, 1),
        "landmarks": n * per_drone, "seed": seed, "complete": done,
        "violations": len(violations), "mission_s": round(seconds, 2),
        "wall_s": round(wall, 2),
        "sent": _per_second(net.sent, ids, seconds),
        "received": _per_second(net.received, ids, seconds),
        "state_bytes_mean": round(statistics.mean(sizes), 1), "state_bytes_max": max(sizes),
        "state_peer_ids_max": peer_ids,
    }


_CODEC: Codec[Publication] = Codec(Publication)


@contextlib.contextmanager
def _partners_published(k: int) -> Iterator[None]:
    """States name at most ``k`` partners meanwhile (the core reads the constant per state)."""
    before = published.PARTNERS_PUBLISHED
    setattr(published, "PARTNERS_PUBLISHED", k)  # noqa: B010 (a Final, for this bench only)
    try:
        yield
    finally:
        setattr(published, "PARTNERS_PUBLISHED", before)  # noqa: B010


def _state_peer_ids(payload: bytes) -> int:
    """Entries of a state that name peers (partners, trade counts, members, fenced)."""
    st = _CODEC.decode(payload, "state")
    assert isinstance(st, AgentState)
    return len(st.partners) + len(st.trades_with) + len(st.members) + len(st.fenced)


def bench_zenoh(n: int = 5, per_drone: int = PER_DRONE, seconds: float = 20.0,
                rate_scale: float = 1.0) -> dict[str, Any]:
    """Sent traffic per drone of ``n`` real agent processes on a real router, heard by one
    subscriber on ``viscover/<m>/**`` (every publication of every drone, as the wire carries
    it), for ``seconds`` of wall time at real time (``rate_scale`` 1)."""
    import os
    import subprocess
    from pathlib import Path

    from agent.net.router import client_config, start_router_process, stop_router_process
    from agent.net.transport import ZenohTransport

    root = Path(__file__).resolve().parents[1]
    heard: dict[str, Counter[str]] = defaultdict(Counter)
    heard_bytes: dict[str, Counter[str]] = defaultdict(Counter)
    tmp = tempfile.TemporaryDirectory(prefix="viscover-traffic-z-")
    scen = Path(tmp.name) / "swarm.toml"
    scen.write_text(swarm_scene_toml(n, n * per_drone, seed=1))
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(root), env.get("PYTHONPATH")]))
    proc, ep = start_router_process()
    procs: list[subprocess.Popen[bytes]] = []
    tp = ZenohTransport(client_config(ep), None, "bench-traffic")
    mission = f"swarm_{n}_{n * per_drone}"

    counting = [True]

    def on_sample(key: str, payload: bytes) -> None:
        if not counting:
            return
        sender = keys.try_agent_of(key) or "?"
        kind = key.split("/")[2] if key.count("/") >= 3 else "?"
        heard[sender][kind] += 1
        heard_bytes[sender][kind] += len(payload)

    sub = tp.subscribe(f"{keys.ROOT}/{mission}/**", on_sample)
    try:
        for i in range(n):
            procs.append(subprocess.Popen(
                [sys.executable, "-m", "agent.cli", "agent", "--id", f"N{i}", "--scenario",
                 str(scen), "--connect", ep, "--state-dir", str(Path(tmp.name) / f"N{i}"),
                 "--rate-scale", str(rate_scale), "--log-level", "ERROR"],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env))
        deadline = time.monotonic() + 60.0
        while len(heard) < n and time.monotonic() < deadline:
            time.sleep(0.1)  # every drone up: count from here, a window of the mission
        heard.clear()
        heard_bytes.clear()
        time.sleep(seconds)
        counting.clear()  # what arrives later (the departures) is not counted
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
        sub.undeclare()
        tp.close()
        stop_router_process(proc)
        tmp.cleanup()
    ids = [f"N{i}" for i in range(n)]
    msgs = [sum(heard[a].values()) / seconds for a in ids]
    byts = [sum(heard_bytes[a].values()) / seconds for a in ids]
    kinds = sorted({k for c in heard.values() for k in c})
    count = {k: sum(c[k] for c in heard.values()) for k in kinds}
    return {"bench": "traffic_per_drone", "network": "zenoh", "drones": n,
            "landmarks": n * per_drone, "wall_s": seconds, "rate_scale": rate_scale,
            "sent_publications": {"msgs_per_s": round(statistics.mean(msgs), 2),
                                  "bytes_per_s": round(statistics.mean(byts), 1)},
            "by_kind": {k: {"msgs_per_s": round(count[k] / (seconds * n), 2),
                            "bytes_per_msg": round(sum(c[k] for c in heard_bytes.values())
                                                   / count[k], 1)} for k in kinds}}


def _emit(out: TextIO, rec: dict[str, Any]) -> dict[str, Any]:
    out.write(json.dumps(rec) + "\n")
    out.flush()
    return rec


def run(out: TextIO | None = None, sizes: tuple[int, ...] = SIZES, zenoh: bool = True,
        partners: int | None = None, dense: bool = True) -> list[dict[str, Any]]:
    """The ``traffic_per_drone`` rows at each team size, spread and (``dense``) all
    neighbours, and, with ``zenoh``, the real router's check at 5 drones; ``partners``: see
    :func:`bench_memory`."""
    stream = out if out is not None else sys.stdout
    recs = [_emit(stream, bench_memory(n, partners=partners, spread=spread))
            for spread in ((True, False) if dense else (True,)) for n in sizes]
    if zenoh:
        recs.append(_emit(stream, bench_zenoh()))
    return recs


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--sizes", default=",".join(map(str, SIZES)), metavar="N,N,...")
    p.add_argument("--no-zenoh", action="store_true",
                   help="skip the check on real processes (5 drones on a router, 20 s)")
    p.add_argument("--no-dense", action="store_true",
                   help="skip the rows with every drone a neighbour of every other")
    p.add_argument("--all-partners", action="store_true",
                   help="states name every partner, as before PARTNERS_PUBLISHED (the 'before' "
                   "rows)")
    a = p.parse_args(argv)
    run(sys.stdout, tuple(int(x) for x in a.sizes.split(",")), zenoh=not a.no_zenoh,
        partners=10**6 if a.all_partners else None, dense=not a.no_dense)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
