"""The capture attack of the insider campaign (``false_capture`` in ``make chaos-hostile``):
three agent processes inspect the shipped wind turbine (41 landmarks, 39 capturable) on the
secured profile (a TLS router, signed trades) while a hostile insider holding drone C's
certificate rewrites every state C publishes into one that claims every landmark captured:
its captured set all ones, and claims from made-up poses in front of each landmark (the
uncapturable ones too), C's genuine claims kept (:class:`Forger`).

A false capture is a landmark that some drone's own final captured set, or the observer's
count, names captured although no camera captured it: the journals' capture records, each
re-checked from its journaled pose by the independent check
(:func:`bench.inspection.recheck.recheck_records`; a record failing it counts too). Lost and
doubled come from the journals' ledgers. The attack is refused when both honest peers
counted refused claims and nothing false was counted captured.
"""

from __future__ import annotations

import itertools
import json
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import msgspec
import numpy as np

from agent.config.parse import load_scenario
from agent.config.scenario import Scenario
from agent.mission.observer import Observer
from agent.net.pki import TeamPlan, make_team
from agent.net.router import start_router_process, stop_router_process
from agent.net.security import OBSERVER, TeamDir, drone_name
from agent.net.security import client_config as secure_config
from agent.net.transport import ZenohTransport
from agent.protocol.captures import split_claims
from agent.protocol.machine import TradeMachine
from agent.storage.journal import Journal
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.peer import AgentState, CaptureClaim, Publication, pack_bits, unpack_bits
from agent.world.structure import resolve_structure
from agent.world.tables import mission_tables
from bench.inspection.recheck import journal_captures, recheck_records

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "scenarios" / "inspect_wind_turbine.toml"
MISSION = "inspect_wind_turbine"  #: the scenario's name: the mission's key space
THIEF = "C"  #: whose certificate the insider holds
OFFSET = 10**9  #: forged states outrank C's own (same incarnation, higher sequence numbers)
PUB: Codec[Publication] = Codec(Publication)


class Forger:
    """The insider with C's certificate: every genuine state of C is published again, claiming
    every landmark (module docstring); the genuine states of every drone are kept."""

    def __init__(self, team: TeamDir, endpoint: str, sc: Scenario) -> None:
        self.sc = sc
        self.all = pack_bits(np.ones(len(sc.landmark_ids), dtype=np.bool_))
        self.turn = itertools.count()
        self.forged = 0
        self.genuine: dict[str, AgentState] = {}  #: each drone's latest genuine state
        self.lock = threading.Lock()
        self.tp = ZenohTransport(secure_config(team, [endpoint], drone_name(THIEF)), None,
                                 "forger")
        self.sub = self.tp.subscribe(keys.all_agents(MISSION, "state"), self.on_state)

    def lies(self, t: float) -> list[CaptureClaim]:
        """Eight claims at C's time t [s]: one landmark each, from in front of it (d_opt
        along its normal, looking at it), in turn over every landmark; and one of them all."""
        sc, out = self.sc, []
        for _ in range(7):
            j = next(self.turn) % len(sc.landmark_ids)
            p = sc.q[j] + sc.d_opt * sc.u[j]
            out += split_claims(t, p, -sc.u[j], [int(sc.landmark_ids[j])])
        return out + split_claims(t, sc.q[0] + sc.d_opt * sc.u[0], -sc.u[0], sc.landmark_ids)

    def on_state(self, key: str, payload: bytes) -> None:
        """A state heard: kept if genuine; C's published again as the lie."""
        try:
            st = PUB.decode(payload)
        except msgspec.DecodeError:
            return
        if not isinstance(st, AgentState) or st.seq >= OFFSET:
            return  # not a state, or one of ours
        with self.lock:
            self.genuine[st.sender] = st
            if st.sender != THIEF:
                return
            forged = msgspec.structs.replace(
                st, seq=st.seq + OFFSET, captured=self.all,
                claims=(st.claims or [])[-8:] + self.lies(st.t))
            self.tp.publish(key, PUB.encode(forged))
            self.forged += 1

    def close(self) -> None:
        self.sub.undeclare()
        self.tp.close()


def _ledgers(root: Path, sc: Scenario) -> tuple[list[int], list[int]]:
    """The landmarks lost (in no journal's ledger) and doubled (in two)."""
    count: dict[int, int] = {}
    held: set[int] = set()
    for a in sc.agents:
        m = TradeMachine(a.id, list(sc.landmark_ids))
        j = Journal(root / a.id)
        try:
            for rec in j.replay():
                m.apply(rec)
        finally:
            j.close()
        held |= set(m.held)
        for lid in m.owned:
            count[lid] = count.get(lid, 0) + 1
    lost = sorted(set(sc.landmark_ids) - set(count) - held)
    return lost, sorted(lid for lid, n in count.items() if n > 1)


def _agent(aid: str, root: Path, endpoint: str, team: TeamDir) -> subprocess.Popen[str]:
    cmd = [sys.executable, "-m", "agent.cli", "agent", "--id", aid, "--scenario",
           str(SCENARIO), "--connect", endpoint, "--state-dir", str(root / aid),
           "--rate-scale", "10", "--request-timeout", "0.15", "--exit-on-complete",
           "--timeout", "150", "--tls-dir", str(team.path)]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            cwd=ROOT)


def capture_mission(seed: int) -> dict[str, Any]:
    """One inspection with the capture attack (module docstring): the tally (tries,
    refused, false captures and what they are made of), lost, doubled, violations."""
    del seed  # the attack is deterministic; the flight's timing is the machine's
    sc = resolve_structure(load_scenario(SCENARIO))
    table, _ = mission_tables(sc)
    ids = np.asarray(sc.landmark_ids, dtype=np.int64)
    tmp = Path(tempfile.mkdtemp(prefix="viscover-captures-"))
    team = make_team(TeamPlan(tmp / "team", [a.id for a in sc.agents]))
    router, ep = start_router_process(team=team)
    forger = Forger(team, ep, sc)
    obs_tp = ZenohTransport(secure_config(team, [ep], OBSERVER), None, "observer")
    ob = Observer(obs_tp, MISSION, [a.id for a in sc.agents], list(sc.landmark_ids),
                  initial=sc.initial_sets())
    t0 = time.monotonic()
    procs = [_agent(a.id, tmp, ep, team) for a in sc.agents]
    try:
        outs = [p.communicate(timeout=200)[0] for p in procs]
        ob.done.wait(20.0)
        rep = ob.snapshot()
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
        ob.close()
        obs_tp.close()
        forger.close()
        stop_router_process(router)
    lines = {}
    for a, out in zip(sc.agents, outs, strict=True):
        first = next((x for x in out.splitlines() if x.startswith("{")), None)
        lines[a.id] = json.loads(first) if first is not None else {}
    recs = journal_captures(tmp, [a.id for a in sc.agents])
    real = np.isin(ids, sorted({lid for r in recs for lid in r.ids}))
    said = np.zeros(ids.size, dtype=np.bool_)  # what the drones' own final sets name
    for st in forger.genuine.values():
        bits = unpack_bits(st.captured, ids.size) if st.captured else None
        if bits is not None:
            said |= bits
    said_false = int((said & ~real).sum())
    observed = 0 if rep.inspection is None else int(rep.inspection["captured"])
    observer_false = max(0, observed - int(real.sum()))
    counted = max([int(x.get("captured", 0)) for x in lines.values()] + [0])
    agent_false = max(0, counted - int(real.sum()))
    bad_records = recheck_records(sc, recs)
    lost, doubled = _ledgers(tmp, sc)
    honest = [a.id for a in sc.agents if a.id != THIEF]
    refused_by_peers = all(sum(lines[a].get("refused_claims", {}).values()) > 0
                           for a in honest)
    false = said_false + observer_false + agent_false + bad_records
    missed = int((table.capturable & ~real).sum())
    shutil.rmtree(tmp, ignore_errors=True)
    return {"attacks": {"false_capture": {
                "tries": 1, "accepted": int(false > 0), "refused": int(refused_by_peers
                                                                      and false == 0),
                "forged_states": forger.forged, "false_captures": false,
                "said_false": said_false, "observer_false": observer_false,
                "agent_false": agent_false, "bad_records": bad_records,
                "capturable_missed": missed}},
            "lost": lost, "doubled": doubled,
            # the observer also names the insider (C's states come from two processes): that
            # is the attack seen, not a violation of the team's
            "violations": [v for v in rep.violations if not v.startswith(f"agent {THIEF}: ")],
            "insider_flagged": sum(v.startswith(f"agent {THIEF}: ") for v in rep.violations),
            "complete": rep.complete, "wall_s": round(time.monotonic() - t0, 1)}
