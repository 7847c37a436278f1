"""The insider campaign (``make chaos-hostile``): a hostile drone holding a valid
team certificate and signing key, drone C's, while the real C flies with the team (secured
profile: a TLS router, signed trades; real agent processes, ``strategy = "potential"``, so that
re-split legs are taken from stage 2 on). Each attack is tried against a team that completed
its thesis stage, as drone C:

* ``resplit_made_up_pose``: a re-split leg taking all of a peer's landmarks, from a pose in
  front of one of them (C is not there);
* ``resplit_doubling``: a re-split leg from C's own published pose handing a peer landmarks a
  third drone owns (C's published ledger plus them, at the owner's versions);
* ``ordinary_doubling``: an Algorithm-7 offer from C's pose whose set holds a third drone's
  landmarks;
* ``published_made_up_pose``: a made-up pose published under C's certificate (a sequence
  number above the real C's), then at once an offer from it in front of a peer's landmark;
* ``seal_flood``: requests signed with C's key from 60 new incarnation tokens (the replay
  memory of the receiver must stay bounded, its evictions counted and published);
* ``forged_state``: states under C's certificate (incarnation 10⁶) claiming a peer's
  landmarks at its versions, for one second;
* ``false_capture``: C's states rewritten to claim every landmark captured, with claims from
  made-up poses, during an inspection of the wind turbine (its own mission:
  :mod:`bench.chaos_captures`); false captures are landmarks counted captured (by a drone's
  own set, an agent's result or the observer) that no camera captured, re-checked from the
  journaled poses.

Every Accept is followed by a signed Commit (a thief finishing what it got). After the
attacks, the ledgers are read from the agents' journals (lost: a landmark in no ledger;
doubled: in two), and the observer's report is checked (violations). One line per mission and
the table (attack, runs, refused, lost, doubled, false captures) are printed; a JSON line per
row goes to ``bench/results.jsonl``.

``python -m bench.chaos_insider [--runs N] [--attacks a,b]``.
"""

from __future__ import annotations

import argparse
import json
import random
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agent.config.parse import load_scenario
from agent.config.scenario import Scenario
from agent.mission.observer import Observer, fence_keys
from agent.net.pki import TeamPlan, make_team
from agent.net.router import start_router_process, stop_router_process
from agent.net.security import TeamDir, drone_name, load_signing
from agent.net.security import client_config as secure_config
from agent.net.transport import ZenohTransport
from agent.protocol.machine import TradeMachine
from agent.protocol.regroup import leg_terms
from agent.storage.journal import Journal
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.peer import (
    Accept,
    AgentState,
    Commit,
    Counters,
    Offer,
    Pose,
    Publication,
    Reply,
    Request,
    RoundQuery,
    pack,
    pack_arrays,
    unpack,
)
from agent.wire.signed import REASON_STALE, Refusal, TradeSeal
from bench.bench_trade import swarm_scene_toml
from bench.chaos_captures import capture_mission

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results.jsonl"
TEAM = ["N0", "N1", "N2"]
THIEF = "N2"  #: whose certificate and key the insider holds (drone C of the issue)
REQ: Codec[Request] = Codec(Request)
REP: Codec[Reply] = Codec(Reply)
PUB: Codec[Publication] = Codec(Publication)
Vec3 = tuple[float, float, float]


def _v(x: Any) -> Vec3:
    a = np.asarray(x, dtype=np.float64).reshape(3)
    return (float(a[0]), float(a[1]), float(a[2]))


@dataclass
class Tally:
    """What one attack tried and got."""

    tries: int = 0
    refused: int = 0  #: answered anything but Accept (or not at all)
    accepted: int = 0
    evicted: int = 0  #: seal_flood: entries the victim says it evicted
    notes: list[str] = field(default_factory=list)


class Insider:
    """Drone C's certificate and signing key in hostile hands (module docstring)."""

    def __init__(self, team: TeamDir, endpoint: str, sc: Scenario, seed: int) -> None:
        self.sc, self.m, self.team, self.endpoint = sc, sc.name, team, endpoint
        self.rng = random.Random(seed)
        self.tp = ZenohTransport(secure_config(team, [endpoint], drone_name(THIEF)), None,
                                 "insider")
        self.seal = TradeSeal(load_signing(team, THIEF), sc.name)
        self.states: dict[str, AgentState] = {}
        self.poses: dict[str, Pose] = {}
        self._lock = threading.Lock()
        self._ctr = 0
        self._handles = [
            self.tp.subscribe(keys.all_agents(self.m, "state"), self._on_state),
            self.tp.subscribe(keys.all_agents(self.m, "pose"), self._on_pose),
        ]

    def close(self) -> None:
        for h in self._handles:
            h.undeclare()
        self.tp.close()

    def _on_state(self, key: str, payload: bytes) -> None:
        msg = PUB.decode(payload, key)
        if isinstance(msg, AgentState) and msg.incarnation < 1_000_000:
            with self._lock:
                old = self.states.get(msg.sender)
                if old is None or (msg.incarnation, msg.seq) > (old.incarnation, old.seq):
                    self.states[msg.sender] = msg

    def _on_pose(self, key: str, payload: bytes) -> None:
        msg = PUB.decode(payload, key)
        if isinstance(msg, Pose) and msg.seq < 1_000_000:
            with self._lock:
                self.poses[msg.sender] = msg

    # -- helpers ------------------------------------------------------------------------------
    def owned(self, aid: str) -> tuple[np.ndarray, np.ndarray]:
        with self._lock:
            st = self.states.get(aid)
        got = None if st is None else unpack(st.owned)
        if got is None:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        return got[0], got[1]

    def thief_pose(self) -> tuple[Vec3, Vec3]:
        """The real C's latest published pose (a thief copies it)."""
        with self._lock:
            p = self.poses.get(THIEF)
            st = self.states.get(THIEF)
        if p is not None:
            return p.p, p.v
        assert st is not None, "no pose of C heard"
        return st.p, st.v

    def in_front(self, lid: int) -> tuple[Vec3, Vec3]:
        j = self.sc.landmark_ids.index(lid)
        p = self.sc.q[j] + self.sc.d_opt * self.sc.u[j]
        u = self.sc.u[j] / max(1e-9, float(np.linalg.norm(self.sc.u[j])))
        return _v(np.append(p, 0.0)[:3] if p.size == 2 else p), \
            _v(np.append(-u, 0.0)[:3] if u.size == 2 else -u)

    def tid(self) -> str:
        self._ctr += 1
        return f"{THIEF}:999:{self._ctr}"

    def ask(self, to: str, req: Request, seal: TradeSeal | None = None) -> Reply | None:
        seal = seal or self.seal
        for _ in range(3):
            data, nonce = seal.seal_request(REQ.encode(req), to)
            raw = self.tp.request(keys.trade_key(self.m, to), data, 0.5)
            if raw is None:
                continue
            body = seal.open_reply(raw, to, nonce)
            if isinstance(body, Refusal):
                if body.reason == REASON_STALE:
                    continue
                return None
            return REP.decode(body)
        return None

    def offer_and_commit(self, to: str, offer: Offer, tally: Tally) -> None:
        """Send ``offer`` (asked again while Busy, as an honest initiator would, for about a
        second); on an Accept, Commit it."""
        tally.tries += 1
        reply: Reply | None = None
        for k in range(8):
            reply = self.ask(to, offer)
            if reply is None or type(reply).__name__ != "Busy":
                break
            time.sleep(0.15)
            offer = Offer(sender=offer.sender, trade_id=self.tid(), p=offer.p, v=offer.v,
                          owned=offer.owned, regroup=offer.regroup) if k % 2 else offer
        if isinstance(reply, Accept):
            tally.accepted += 1
            done = self.ask(to, Commit(sender=THIEF, trade_id=offer.trade_id))
            tally.notes.append(f"accepted by {to}, commit {type(done).__name__}")
        else:
            tally.refused += 1
            tally.notes.append(f"{to}: {type(reply).__name__ if reply else 'no reply'}"
                               + (f" {getattr(reply, 'reason', '')}" if reply else ""))

    def victims(self) -> tuple[str, str]:
        """(the peer with the most landmarks, the other peer)."""
        a, b = [x for x in TEAM if x != THIEF]
        return (a, b) if self.owned(a)[0].size >= self.owned(b)[0].size else (b, a)

    # -- attacks --------------------------------------------------------------------------
    def resplit_made_up_pose(self, tally: Tally) -> None:
        victim, _ = self.victims()
        r_ids, r_vers = self.owned(victim)
        c_ids, c_vers = self.owned(THIEF)
        if not r_ids.size:
            tally.notes.append("victim owns nothing")
            return
        terms = leg_terms(r_ids[:0], _goal(), c_ids, c_vers, r_ids, r_vers)
        p, v = self.in_front(int(r_ids[0]))
        self.offer_and_commit(victim, Offer(sender=THIEF, trade_id=self.tid(), p=p, v=v,
                                            owned=pack_arrays(c_ids, c_vers),
                                            regroup=terms), tally)

    def resplit_doubling(self, tally: Tally) -> None:
        donor, to = self.victims()
        d_ids, d_vers = self.owned(donor)
        r_ids, r_vers = self.owned(to)
        c_ids, c_vers = self.owned(THIEF)
        if not d_ids.size:
            tally.notes.append("donor owns nothing")
            return
        i_ids, i_vers = np.concatenate([c_ids, d_ids]), np.concatenate([c_vers, d_vers])
        terms = leg_terms(np.concatenate([r_ids, d_ids]), _goal(), i_ids, i_vers, r_ids, r_vers)
        p, v = self.thief_pose()
        self.offer_and_commit(to, Offer(sender=THIEF, trade_id=self.tid(), p=p, v=v,
                                        owned=pack_arrays(i_ids, i_vers), regroup=terms), tally)

    def ordinary_doubling(self, tally: Tally) -> None:
        donor, to = self.victims()
        d_ids, d_vers = self.owned(donor)
        c_ids, c_vers = self.owned(THIEF)
        p, v = self.thief_pose()
        self.offer_and_commit(to, Offer(
            sender=THIEF, trade_id=self.tid(), p=p, v=v,
            owned=pack_arrays(np.concatenate([c_ids, d_ids]), np.concatenate([c_vers, d_vers]))),
            tally)

    def published_made_up_pose(self, tally: Tally) -> None:
        victim, _ = self.victims()
        r_ids, _ = self.owned(victim)
        c_ids, c_vers = self.owned(THIEF)
        if not r_ids.size:
            tally.notes.append("victim owns nothing")
            return
        p, v = self.in_front(int(self.rng.choice(r_ids.tolist())))
        seq = 2_000_000 + self._ctr
        for _ in range(3):  # published under C's certificate, then at once the offer
            self.tp.publish(keys.pose_key(self.m, THIEF),
                            PUB.encode(Pose(sender=THIEF, seq=seq, t=0.0, p=p, v=v)))
            seq += 1
        time.sleep(0.01)
        self.offer_and_commit(victim, Offer(sender=THIEF, trade_id=self.tid(), p=p, v=v,
                                            owned=pack_arrays(c_ids, c_vers)), tally)

    def seal_flood(self, tally: Tally) -> None:
        victim, _ = self.victims()
        keys_c = load_signing(self.team, THIEF)
        boot = 0
        for k in range(60):  # 60 processes of C (a flood of new incarnation tokens)
            seal = TradeSeal(keys_c, self.m)
            if boot:
                seal.know(victim, boot)
            self.ask(victim, RoundQuery(sender=THIEF, epoch=1), seal)
            boot = seal.peer_boot(victim) or boot
            tally.tries += k == 0
        time.sleep(1.0)
        with self._lock:
            st = self.states.get(victim)
        tally.evicted = 0 if st is None else st.counters.evicted
        tally.refused += tally.evicted > 0  # bounded, and the evictions shown

    def forged_state(self, tally: Tally) -> None:
        donor, _ = self.victims()
        d_ids, d_vers = self.owned(donor)
        c_ids, c_vers = self.owned(THIEF)
        claims = {int(i): int(v) for i, v in zip([*c_ids, *d_ids], [*c_vers, *d_vers],
                                                  strict=True)}
        p, v = self.thief_pose()
        tally.tries += 1
        for seq in range(1, 6):
            st = AgentState(sender=THIEF, incarnation=1_000_000, seq=seq, t=0.0, p=p, v=v,
                            phase="converged", owned=pack(claims), held=pack({}), vision=0.0,
                            counters=Counters(), partners=[], pending=[], trades_with={})
            self.tp.publish(keys.state_key(self.m, THIEF), PUB.encode(st))
            time.sleep(0.2)
        tally.refused += 1  # judged by the ledgers and the observer afterwards


def _goal() -> Any:
    from agent.core.coverage_moves import Goal

    return Goal(np.zeros(3), np.array([1.0, 0.0, 0.0]), 0.0)


#: attack name -> the insider's method running it once after the team's thesis stage
ATTACKS: dict[str, Callable[[Insider, Tally], None]] = {
    "resplit_made_up_pose": Insider.resplit_made_up_pose,
    "resplit_doubling": Insider.resplit_doubling,
    "ordinary_doubling": Insider.ordinary_doubling,
    "published_made_up_pose": Insider.published_made_up_pose,
    "seal_flood": Insider.seal_flood,
    "forged_state": Insider.forged_state,
}
#: every attack of the campaign: those of :data:`ATTACKS`, and the capture attack, which
#: needs an inspection mission of its own (:func:`bench.chaos_captures.capture_mission`)
CAMPAIGN = (*ATTACKS, "false_capture")


def _agent(aid: str, scene: Path, endpoint: str, tmp: Path, team: TeamDir
           ) -> subprocess.Popen[bytes]:
    """Agent ``aid``'s process, its output in ``tmp/<aid>.log``."""
    cmd = [sys.executable, "-m", "agent.cli", "agent", "--id", aid, "--scenario", str(scene),
           "--connect", endpoint, "--state-dir", str(tmp / aid), "--rate-scale", "10",
           "--request-timeout", "0.15", "--timeout", "300", "--tls-dir", str(team.path)]
    with (tmp / f"{aid}.log").open("wb") as log:  # the child keeps its own descriptor
        return subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT)


def _ledgers(tmp: Path, sc: Scenario) -> dict[str, tuple[set[int], set[int]]]:
    """Each agent's (owned, held) from its journal."""
    out = {}
    for aid in TEAM:
        m = TradeMachine(aid, list(sc.landmark_ids))
        j = Journal(tmp / aid)
        try:
            for rec in j.replay():
                m.apply(rec)
        finally:
            j.close()
        out[aid] = (set(m.owned), set(m.held))
    return out


def mission(attacks: list[str], seed: int, complete_s: float = 120.0) -> dict[str, Any]:
    """One mission of the team, every attack of ``attacks`` tried once after its thesis
    stage; its JSON-able result (per attack tallies, lost, doubled, violations)."""
    rng = random.Random(seed)
    tmp = Path(tempfile.mkdtemp(prefix=f"viscover-insider-{seed}-"))
    team = make_team(TeamPlan(tmp / "team", TEAM))
    scene = tmp / "scene.toml"
    scene.write_text('strategy = "potential"\nlost_after = 0.0\n'
                     + swarm_scene_toml(len(TEAM), 12, seed).replace(
                         'name = "swarm', 'name = "insider', 1))
    sc = load_scenario(scene)
    router, ep = start_router_process(team=team)
    obs_tp = ZenohTransport(secure_config(team, [ep], "observer"), None, "insider-observer")
    ob = Observer(obs_tp, sc.name, TEAM, list(sc.landmark_ids), initial=sc.initial_sets(),
                  fence_keys=fence_keys(team.path))
    procs = [_agent(a, scene, ep, tmp, team) for a in TEAM]
    insider = Insider(team, ep, sc, rng.randrange(2**31))
    tallies = {a: Tally() for a in attacks}
    t0 = time.monotonic()
    try:
        if not ob.done.wait(complete_s):
            raise RuntimeError(f"the team did not complete within {complete_s:.0f} s")
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and not all(a in insider.states for a in TEAM):
            time.sleep(0.1)
        time.sleep(1.0)
        for name in attacks:
            ATTACKS[name](insider, tallies[name])
            time.sleep(0.5)
        time.sleep(6.0)  # longer than the observer's lost / doubled bound (5 s)
        rep = ob.snapshot()
        alive = [p.poll() is None for p in procs]
    finally:
        insider.close()
        for p in procs:
            if p.poll() is None:
                p.terminate()
        for p in procs:
            try:
                p.wait(20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        ob.close()
        obs_tp.close()
        stop_router_process(router)
    ledgers = _ledgers(tmp, sc)
    count: dict[int, int] = {}
    for own, _held in ledgers.values():
        for lid in own:
            count[lid] = count.get(lid, 0) + 1
    held = set().union(*(h for _o, h in ledgers.values()))
    lost = sorted(set(sc.landmark_ids) - set(count) - held)
    doubled = sorted(lid for lid, n in count.items() if n > 1)
    return {"seed": seed, "attacks": {a: vars(t) for a, t in tallies.items()},
            "lost": lost, "doubled": doubled, "violations": rep.violations,
            "conflicting": len(rep.conflicting), "agents_alive": alive,
            "wall_s": round(time.monotonic() - t0, 1), "tmp": str(tmp)}


def table(rows: list[dict[str, Any]]) -> str:
    """The campaign's table (module docstring)."""
    head = "| attack | runs | refused | lost | doubled | false captures |"
    out = [head, "|---|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['attack']} | {r['runs']} | {r['refused']}/{r['tries']} | "
                   f"{r['lost']} | {r['doubled']} | {r['false_captures']} |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.chaos_insider", description=__doc__)
    ap.add_argument("--runs", type=int, default=2, help="missions per attack")
    ap.add_argument("--attacks", default=",".join(CAMPAIGN), help="comma-separated")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    names = [a for a in args.attacks.split(",") if a]
    if unknown := [a for a in names if a not in CAMPAIGN]:
        ap.error(f"unknown attack {unknown[0]!r} (known: {', '.join(CAMPAIGN)})")
    rows: list[dict[str, Any]] = []
    for name in names:
        row = {"attack": name, "runs": 0, "tries": 0, "refused": 0, "lost": 0, "doubled": 0,
               "false_captures": 0, "violations": 0}
        for k in range(args.runs):
            seed = args.seed + 101 * k + len(rows)
            got = capture_mission(seed) if name == "false_capture" else mission([name], seed)
            t = got["attacks"][name]
            row["runs"] += 1
            row["tries"] += t["tries"]
            row["refused"] += t["refused"]
            row["lost"] += len(got["lost"])
            row["doubled"] += len(got["doubled"])
            row["violations"] += len(got["violations"])
            row["false_captures"] += t.get("false_captures", 0)
            print(json.dumps({k2: v for k2, v in got.items() if k2 != "tmp"}),
                  file=sys.stderr, flush=True)
        rows.append(row)
    with RESULTS.open("a") as f:
        for r in rows:
            f.write(json.dumps({"bench": "chaos_insider", **r}) + "\n")
    print(table(rows))
    bad = sum(r.get("lost", 0) + r.get("doubled", 0) + r.get("violations", 0) for r in rows)
    bad += sum(r.get("tries", 0) - r.get("refused", 0) for r in rows)
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
