"""The hostile authenticated drone of the chaos campaign (:mod:`bench.chaos`): N5, with its
own team certificate and signing key and N4's stolen signing key. Every 0.3 s it

* publishes its own state naming N0 and N1 fenced out, with a proof whose ballots it signed
  alone (in the names of N2, N3 and itself);
* offers to one of N0-N3, signed with N4's key, from a made-up pose in front of a random
  landmark, and sends Commit for any Accept it gets;
* sends junk to that agent's trade queryable.

It never runs as an agent (no liveliness token): the team fences N5 after ``lost_after`` and
adopts its scenario landmarks."""

from __future__ import annotations

import random
import threading
from collections import Counter

import numpy as np

from agent.config.scenario import Scenario
from agent.net.security import TeamDir, drone_name, load_signing
from agent.net.security import client_config as secure_config
from agent.net.transport import ZenohTransport
from agent.protocol.fence_proof import make_proof
from agent.wire import keys
from agent.wire.ballots import sign_ballot
from agent.wire.codec import Codec
from agent.wire.peer import (
    Accept,
    AgentState,
    Commit,
    Counters,
    Offer,
    Publication,
    Reply,
    Request,
    pack,
)
from agent.wire.signed import REASON_STALE, Refusal, SigningKeys, TradeSeal

REQ: Codec[Request] = Codec(Request)
REP: Codec[Reply] = Codec(Reply)
PUB: Codec[Publication] = Codec(Publication)
VICTIMS = ["N0", "N1"]


class Hostile:
    """N5 (see the module docstring); :meth:`stats` counts what it tried and got."""

    def __init__(self, team: TeamDir, endpoint: str, sc: Scenario, seed: int) -> None:
        self.sc = sc
        self.m = sc.name
        self.rng = random.Random(seed)
        self.tp: ZenohTransport | None = None
        self.team, self.endpoint = team, endpoint
        self.own = load_signing(team, "N5")
        self.stolen = TradeSeal(load_signing(team, "N4"), sc.name)
        self.counts: Counter[str] = Counter()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self.tp = ZenohTransport(secure_config(self.team, [self.endpoint], drone_name("N5")),
                                 None, "N5")
        self._thread = threading.Thread(target=self._loop, name="hostile", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(10.0)
            self._thread = None
        if self.tp is not None:
            self.tp.close()
            self.tp = None

    def stats(self) -> dict[str, int]:
        return dict(self.counts)

    def _ask(self, to: str, req: Request) -> Reply | None:
        assert self.tp is not None
        for _ in range(2):
            data, nonce = self.stolen.seal_request(REQ.encode(req), to)
            raw = self.tp.request(keys.trade_key(self.m, to), data, 0.3)
            if raw is None:
                return None
            body = self.stolen.open_reply(raw, to, nonce)
            if isinstance(body, Refusal):
                if body.reason == REASON_STALE:
                    continue
                return None
            return REP.decode(body)
        return None

    def _state(self, seq: int) -> bytes:
        sigs = {v: sign_ballot(SigningKeys(v, self.own.private, self.own.team), self.m, 9,
                               "N2", VICTIMS) for v in ("N2", "N3", "N5")}
        mine = self.sc.initial_sets().get("N5", [])
        st = AgentState(
            sender="N5", incarnation=1, seq=seq, t=0.0, p=(0.0, 0.0, 0.0), v=(1.0, 0.0, 0.0),
            phase="converged", owned=pack(dict.fromkeys((int(x) for x in mine), 0)),
            held=pack({}), vision=0.0, counters=Counters(), partners=[], pending=[],
            trades_with={}, fenced=VICTIMS, fence_epoch=9,
            fence_proofs=[make_proof(9, "N2", VICTIMS, sigs)])
        return PUB.encode(st)

    def _loop(self) -> None:
        assert self.tp is not None
        seq = ctr = 0
        targets = ["N0", "N1", "N2", "N3"]
        while not self._stop.wait(0.3):
            seq += 1
            self.tp.publish(keys.state_key(self.m, "N5"), self._state(seq))
            self.counts["forged_states"] += 1
            to = self.rng.choice(targets)
            j = self.rng.randrange(len(self.sc.landmark_ids))
            p = self.sc.q[j] + self.sc.d_opt * self.sc.u[j]
            v = -self.sc.u[j] / max(1e-9, float(np.linalg.norm(self.sc.u[j])))
            ctr += 1
            tid = f"N4:999:{ctr}"
            offer = Offer(sender="N4", trade_id=tid, p=(float(p[0]), float(p[1]), float(p[2])),
                          v=(float(v[0]), float(v[1]), float(v[2])), owned=pack({}))
            reply = self._ask(to, offer)
            self.counts[f"offer_{type(reply).__name__ if reply else 'none'}"] += 1
            if isinstance(reply, Accept):
                done = self._ask(to, Commit(sender="N4", trade_id=tid))
                self.counts[f"commit_{type(done).__name__ if done else 'none'}"] += 1
            self.tp.request(keys.trade_key(self.m, to), self.rng.randbytes(64), 0.2)
            self.counts["junk"] += 1
