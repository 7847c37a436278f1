"""Ownership invariants, pure (used by the tests on in-memory ledgers and by the observer,
:mod:`agent.mission.observer`, on published states):

* :func:`snapshot_violations`: on a *consistent* snapshot of every agent's ledger, each
  landmark has at least one claim (owned or held) and, at its highest version, exactly one
  claimant, which holds no other claim on it.
* :class:`VersionHistory`: order-independent check over every state ever received: a
  (landmark, version) pair is created once, so it may be claimed by one agent only. A
  landmark owned by two agents, a duplicated transfer or an abort on one side and a commit
  on the other all show up here sooner or later, whatever order the states arrive in.
* :func:`final_violations`: at completion (nothing pending anywhere), every landmark is owned
  (not held) by exactly one agent at its highest version ever seen.
* :class:`LandmarkWatch`: a landmark in no ledger for long was lost between ledgers; one a
  fenced agent held is orphaned until adopted.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

#: claims per agent: (owned {id: version}, held {id: version})
Claims = Mapping[str, tuple[Mapping[int, int], Mapping[int, int]]]
#: one agent's claims: (owned {id: version}, held {id: version})
Claim = tuple[dict[int, int], dict[int, int]]


def snapshot_violations(claims: Claims, all_ids: Iterable[int]) -> list[str]:
    """Violations of the ownership invariant in a consistent snapshot (see module doc)."""
    out: list[str] = []
    per: dict[int, list[tuple[int, str, str]]] = {}
    for agent, (owned, held) in claims.items():
        for lid, ver in owned.items():
            per.setdefault(lid, []).append((ver, agent, "owned"))
        for lid, ver in held.items():
            per.setdefault(lid, []).append((ver, agent, "held"))
    for lid in all_ids:
        cl = per.get(int(lid))
        if not cl:
            out.append(f"landmark {lid}: no claim (lost)")
            continue
        top = max(c[0] for c in cl)
        at_top = [c for c in cl if c[0] == top]
        if len(at_top) != 1:
            out.append(f"landmark {lid}: {len(at_top)} claims at version {top}: {at_top}")
        owners = [c for c in cl if c[2] == "owned"]
        if len(owners) > 1:
            out.append(f"landmark {lid}: owned by {len(owners)} agents: {owners}")
    return out


def final_violations(claims: Claims, all_ids: Iterable[int],
                     highest: Mapping[int, int] | None = None) -> list[str]:
    """At completion: exactly one owner per landmark, nothing held, highest version."""
    out = snapshot_violations(claims, all_ids)
    count: dict[int, int] = {}
    for agent, (owned, held) in claims.items():
        if held:
            out.append(f"agent {agent}: still holds {sorted(held)} at completion")
        for lid, ver in owned.items():
            count[lid] = count.get(lid, 0) + 1
            if highest is not None and ver < highest.get(lid, ver):
                out.append(f"landmark {lid}: {agent} owns stale version {ver} "
                           f"< {highest[lid]}")
    out.extend(f"landmark {lid}: {n} owners" for lid, n in count.items() if n > 1)
    return out


class VersionHistory:
    """(landmark, version) -> agent, over every claim ever seen (order independent)."""

    def __init__(self) -> None:
        self.creator: dict[tuple[int, int], str] = {}
        self.highest: dict[int, int] = {}

    def add(self, agent: str, owned: Mapping[int, int], held: Mapping[int, int]) -> list[str]:
        """Record ``agent``'s claims; return violations (a pair claimed by two agents)."""
        out: list[str] = []
        for d in (owned, held):
            for lid, ver in d.items():
                k = (lid, ver)
                prev = self.creator.setdefault(k, agent)
                if prev != agent:
                    out.append(f"landmark {lid} version {ver} claimed by {prev} and {agent}")
                if ver > self.highest.get(lid, -1):
                    self.highest[lid] = ver
        return out

    def forget(self, agent: str) -> set[int]:
        """Void every claim of ``agent``: the team fenced it out (its ledger was dropped and
        its landmarks adopted at new versions), so its pairs belong to nobody. Returns the
        landmarks it had claimed."""
        touched = {lid for (lid, _v), a in self.creator.items() if a == agent}
        self.creator = {k: a for k, a in self.creator.items() if a != agent}
        self.highest = {}
        for lid, ver in self.creator:
            if ver > self.highest.get(lid, -1):
                self.highest[lid] = ver
        return touched


class LandmarkWatch:
    """Landmarks in no agent's latest claims: *orphaned* if a fenced agent ever held them
    (adoption will give them an owner), else *missing*; missing for longer than ``lost_s``
    [s] (longer than a lossy link can delay the receiver's state) is a violation: the landmark
    left its owner's ledger and arrived nowhere."""

    def __init__(self, all_ids: Iterable[int], lost_s: float = 5.0) -> None:
        self.all_ids = np.unique(np.fromiter(all_ids, dtype=np.int64))
        self.lost_s = lost_s
        self.since: dict[int, float] = {}  #: unclaimed landmark -> since when [s]
        self.fenced_touched: set[int] = set()
        self._reported: set[int] = set()

    def update(self, claims: Iterable[tuple[Mapping[int, int], Mapping[int, int]]],
               now: float, history: VersionHistory) -> list[str]:
        """New latest claims at time ``now`` [s]; returns new violations."""
        parts = [np.fromiter(d.keys(), dtype=np.int64, count=len(d))
                 for pair in claims for d in pair]
        claimed = np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)
        unclaimed = np.setdiff1d(self.all_ids, claimed).tolist()
        self.since = {lid: self.since.get(lid, now) for lid in unclaimed}
        out = []
        for lid in unclaimed:  # normally none or a few in flight
            if lid in self.fenced_touched or lid in self._reported \
                    or now - self.since[lid] <= self.lost_s or lid not in history.highest:
                continue
            self._reported.add(lid)
            ver = history.highest[lid]
            out.append(f"landmark {lid}: in no agent's ledger for {now - self.since[lid]:.1f} s "
                       f"(last claimed at version {ver} by {history.creator[(lid, ver)]}): lost")
        return out

    def orphaned(self, now: float) -> dict[int, float]:
        """{landmark: seconds unclaimed} of landmarks a fenced agent held."""
        return {lid: round(now - t, 3) for lid, t in self.since.items()
                if lid in self.fenced_touched}
