"""The fence record a router keeps: the team's final word for a drone that comes back late.

:class:`FenceKeeper` runs inside the router process (``viscover router``,
:func:`agent.net.router.run_router`), which outlives the agents: on the router's own session it
listens to every agent state of every mission (``viscover/*/state/*``) and answers queries on
``viscover/<m>/fences`` with a :class:`~agent.wire.record.FenceRecord` (module docstring there):
the fence proofs the states carried, the highest incarnation heard of each agent, and who
reported complete. A drone asks for it before it reports the mission complete, and a drone
whose journal is new asks whether the team heard its id before
(:mod:`agent.runtime.fencing.final_word`).

Nothing here is trusted by the drone that asks: every proof is checked by it as any proof
(signed ballots of a majority on the secured profile). What a hostile publisher can do to the
record is bounded:

* each sender contributes the proofs of its latest state that carried any (at most
  :data:`~agent.wire.peer.MAX_FENCE_PROOFS`); the record lists first the proofs most senders
  carried (a true fence is carried by every survivor), at most
  :data:`~agent.wire.record.MAX_RECORD_PROOFS`;
* an agent counts as *seen* at an incarnation only after two states of that incarnation with
  increasing sequence numbers (one forged message does not make a drone look known);
* on the router's own clock it keeps when each agent's liveliness token came up and when each
  agent was last heard (a state, or its token going): the record says how long each live
  agent has been up and how long each other one has been silent, so a drone whose journal is
  new can tell a run under way (a live agent up since before it went silent) from a new run
  of the mission on this long-running router (everyone started after it left);
* at most :data:`MAX_MISSIONS` missions and :data:`~agent.wire.peer.MAX_IDS` senders per
  mission are kept (the oldest mission heard is forgotten first), and at most one undecoded
  state per key waits for the keeper's thread (a flood replaces, never queues).

With a state directory (``viscover router --state-dir``) the record survives a restart of the
router (:mod:`agent.net.keeper_store`).

Zenoh callbacks only copy and hand over (:class:`~agent.net.worker.Worker`); decoding and
replies run on the keeper's own thread.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import msgspec

from agent.net.keeper_store import StoredMission, StoredRecords, load_records, save_records
from agent.net.rejects import LockedRejectCounter, rate_limited_log
from agent.net.worker import Worker
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.peer import MAX_IDS, AgentState, FenceProof, Publication
from agent.wire.record import MAX_RECORD_PROOFS, RECORD_CODEC, FenceRecord

_log = logging.getLogger(f"viscover.{__name__}")

#: Missions one keeper remembers.
MAX_MISSIONS: Final = 256
#: Seconds a change waits before the record is written (changes meanwhile share the write).
SAVE_DELAY_S: Final = 0.2
#: A token that goes and comes back within this many seconds [router clock] kept its life:
#: when a session closes the router may withdraw the tokens it learned through it and
#: announce them again from their own sessions (seen 0.27 s apart on a loaded machine), which
#: must not make a team under way look newly started (:func:`agent.runners.recovery.
#: under_way`); no drone process restarts that fast.
BLIP_S: Final = 1.0


@dataclass
class _Mission:
    """What the keeper heard of one mission."""

    proofs: dict[str, list[FenceProof]] = field(default_factory=dict)  #: sender -> proofs
    #: sender -> (incarnation, its first seq heard, states heard of it)
    streams: dict[str, tuple[int, int, int]] = field(default_factory=dict)
    seen: dict[str, int] = field(default_factory=dict)  #: confirmed highest incarnation
    complete: set[str] = field(default_factory=set)
    alive_since: dict[str, float] = field(default_factory=dict)  #: live sender -> token up at
    last_heard: dict[str, float] = field(default_factory=dict)  #: sender -> last state/token
    #: live sender -> the highest incarnation of its states since its token came up
    life_inc: dict[str, int] = field(default_factory=dict)
    #: sender whose token just went -> (its life's alive_since, life_inc, when it went)
    gone: dict[str, tuple[float, int | None, float]] = field(default_factory=dict)


class FenceKeeper:
    """Keeps the fence record of every mission heard on ``session`` (module docstring).

    Args:
        session: the router's own ``zenoh.Session``.
        now: the router's clock [s] (monotonic).
        state_dir: where the record is kept across restarts (None: in memory only).
    """

    def __init__(self, session: Any, now: Callable[[], float] = time.monotonic,
                 state_dir: Path | None = None) -> None:
        self._now = now
        self._state_dir = state_dir
        self._save_failed = False
        self._save_queued = False
        self.rejects = LockedRejectCounter()
        self._codec: Codec[Publication] = Codec(
            Publication, counter=self.rejects, log=rate_limited_log(_log))
        self._lock = threading.Lock()
        self._missions: dict[str, _Mission] = {}
        self._pending: dict[str, bytes] = {}  #: key -> newest undecoded state
        self._worker = Worker("fence-keeper")
        if state_dir is not None:
            self._restore(load_records(state_dir))
        self._handles = [
            session.declare_subscriber(f"{keys.ROOT}/*/state/*", self._on_sample),
            session.declare_queryable(keys.every_mission("fences"), self._on_query),
            session.liveliness().declare_subscriber(f"{keys.ROOT}/*/alive/*", self._on_token,
                                                    history=True),
        ]

    def close(self) -> None:
        """Undeclare and stop the keeper's thread."""
        for h in self._handles:
            try:
                h.undeclare()
            except Exception:  # pragma: no cover - the session closed first
                _log.debug("undeclare failed", exc_info=True)
        self._worker.stop()
        if self._save_queued:
            self.flush()

    # -- states (Zenoh thread: copy and hand over) -----------------------------------------------
    def _on_sample(self, sample: Any) -> None:
        key = str(sample.key_expr)
        payload = sample.payload.to_bytes()
        with self._lock:
            first = key not in self._pending
            self._pending[key] = payload
        if first:
            self._worker.submit(lambda: self._take(key))

    def _on_token(self, sample: Any) -> None:
        key = str(sample.key_expr)
        up = "PUT" in str(sample.kind)
        self._worker.submit(lambda: self.token(key, up))

    def _take(self, key: str) -> None:
        with self._lock:
            payload = self._pending.pop(key, None)
        if payload is not None:
            self.add_state(key, payload)

    def add_state(self, key: str, payload: bytes) -> None:
        """Record the state ``payload`` received on ``key`` (anything else is counted)."""
        try:
            mission, kind, agent = keys.parse_key(key)
        except keys.KeyFormatError:
            return
        msg = self._codec.decode(payload, key)
        if kind != "state" or not isinstance(msg, AgentState) or msg.sender != agent:
            if msg is not None:
                self._codec.reject("impossible", key, "not a state of the agent its key names")
            return
        with self._lock:
            m = self._mission(mission)
            if m is None or (agent not in m.streams and len(m.streams) >= MAX_IDS):
                return
            inc, first, n = m.streams.get(agent, (-1, 0, 0))
            changed = False
            if msg.incarnation != inc:
                if msg.incarnation > inc or m.seen.get(agent, -1) < inc:
                    m.streams[agent] = (msg.incarnation, msg.seq, 1)
            elif msg.seq > first:
                m.streams[agent] = (inc, first, n + 1)
                if msg.incarnation > m.seen.get(agent, -1):
                    m.seen[agent] = msg.incarnation
                    changed = True
            m.last_heard[agent] = self._now()
            if agent in m.alive_since:
                m.life_inc[agent] = max(m.life_inc.get(agent, 0), msg.incarnation)
            if msg.fence_proofs and m.proofs.get(agent) != list(msg.fence_proofs):
                m.proofs[agent] = list(msg.fence_proofs)
                changed = True
            if msg.complete and agent not in m.complete:
                m.complete.add(agent)
                changed = True
        if changed:
            self._save()

    def token(self, key: str, up: bool) -> None:
        """An agent's liveliness token on ``key`` came up (``up``) or went."""
        try:
            mission, kind, agent = keys.parse_key(key)
        except keys.KeyFormatError:
            return
        if kind != "alive" or agent is None:
            return
        with self._lock:
            m = self._mission(mission)
            if m is None or (agent not in m.last_heard and len(m.last_heard) >= MAX_IDS):
                return
            now = self._now()
            m.last_heard[agent] = now
            if up:  # a PUT for a token already up (the router repeats them) changes nothing
                if agent not in m.alive_since:
                    back = m.gone.pop(agent, None)
                    if back is not None and now - back[2] <= BLIP_S:  # the same life
                        m.alive_since[agent] = back[0]
                        if back[1] is not None:
                            m.life_inc[agent] = back[1]
                    else:
                        m.alive_since[agent] = now
                        m.life_inc.pop(agent, None)
            else:
                since = m.alive_since.pop(agent, None)
                inc = m.life_inc.pop(agent, None)
                if since is not None:
                    m.gone[agent] = (since, inc, now)

    def _restore(self, stored: StoredRecords) -> None:
        """Take the records kept on disk (module docstring of :mod:`agent.net.keeper_store`)."""
        now = self._now()
        with self._lock:
            for name, sm in list(stored.missions.items())[-MAX_MISSIONS:]:
                m = self._mission(name)
                if m is None:
                    continue
                m.proofs = {a: list(p) for a, p in sm.proofs.items()}
                m.seen = dict(sm.seen)
                m.complete = set(sm.complete)
                m.last_heard = dict.fromkeys(sm.seen, now)  # silent since the restart

    def _save(self) -> None:
        """Have the record written to the state directory, if any: once, after what the
        keeper's thread already has queued (a burst of changes makes one write)."""
        if self._state_dir is None:
            return
        with self._lock:
            if self._save_queued:
                return
            self._save_queued = True
        if not self._worker.submit(self.flush, SAVE_DELAY_S):
            with self._lock:
                self._save_queued = False

    def flush(self) -> None:
        """Write the record to the state directory now (keeper thread). A failure is said
        once and the router runs on (its memory still answers)."""
        if self._state_dir is None:
            return
        with self._lock:
            self._save_queued = False
            records = StoredRecords(missions={
                name: StoredMission(proofs={a: list(p) for a, p in m.proofs.items()},
                                    seen=dict(m.seen), complete=sorted(m.complete))
                for name, m in self._missions.items() if m.seen or m.proofs or m.complete})
        try:
            save_records(self._state_dir, records)
            self._save_failed = False
        except OSError as e:
            if not self._save_failed:
                _log.error("router: cannot keep the fence record in %s (%s): a restart of this "
                           "router would forget it", self._state_dir, e)
            self._save_failed = True

    def _mission(self, mission: str) -> _Mission | None:
        """The record of ``mission`` (made if new; the oldest one forgotten when full)."""
        m = self._missions.get(mission)
        if m is None:
            if len(self._missions) >= MAX_MISSIONS:
                del self._missions[next(iter(self._missions))]
            m = self._missions[mission] = _Mission()
        return m

    # -- queries --------------------------------------------------------------------------------
    def record(self, mission: str) -> FenceRecord:
        """The record of ``mission`` as it stands (empty if nothing was heard of it)."""
        with self._lock:
            m = self._missions.get(mission) or _Mission()
            carried: Counter[bytes] = Counter()
            by_bytes: dict[bytes, FenceProof] = {}
            for proofs in m.proofs.values():
                for p in proofs:
                    raw = msgspec.msgpack.encode(p)
                    carried[raw] += 1
                    by_bytes[raw] = p
            ranked = sorted(by_bytes, key=lambda r: (-carried[r], -by_bytes[r].epoch))
            now = self._now()
            return FenceRecord(
                mission=mission,
                proofs=[by_bytes[r] for r in ranked[:MAX_RECORD_PROOFS]],
                seen=dict(sorted(m.seen.items())[:MAX_IDS]),
                complete=sorted(m.complete)[:MAX_IDS],
                alive_for={a: max(0.0, now - t)
                           for a, t in sorted(m.alive_since.items())[:MAX_IDS]},
                silent_for={a: max(0.0, now - t) for a, t in sorted(
                    (a, t) for a, t in m.last_heard.items() if a not in m.alive_since)[:MAX_IDS]},
                resumed=sorted(a for a, inc in m.life_inc.items()
                               if a in m.alive_since and inc > 1)[:MAX_IDS])

    def _on_query(self, query: Any) -> None:  # Zenoh thread: hand over only
        if not self._worker.submit(lambda: self._answer(query)):
            query.drop()

    def _answer(self, query: Any) -> None:
        key = str(query.key_expr)
        try:
            mission = keys.parse_key(key)[0]
            query.reply(key, RECORD_CODEC.encode(self.record(mission)))
        except keys.KeyFormatError:
            pass  # a wildcard or foreign key: no answer
        except Exception as exc:  # the router is closing; the asker times out
            _log.debug("fence record reply on %s failed: %s", key, exc)
        finally:
            query.drop()
