"""How an inspection mission ended, in one place: every report of the end (``viscover
simulate``'s last line, ``result.json``, the report page, ``viscover launch``, each agent
process, the observer and ``viscover status``) says it with the functions here. Pure: no I/O.

An inspection mission is **complete** only when every capturable landmark is captured. When
the team stops without that (every drone home, with nothing left that one of them will still
try) or its time runs out first (the scenario's ``duration`` in ``viscover simulate``,
``--timeout`` of ``viscover launch`` / ``viscover agent``), it ends **incomplete**, and every
capturable landmark not captured is *given up*, with why:

- ``unreachable``: no viewpoint that captures it could be reached (each flight towards one
  stalled), after :data:`~agent.strategy.inspection.MAX_RETRIES` retries;
- ``blocked``: a viewpoint that captures it was reached, yet the capture did not happen there
  (another drone, the structure or a flown pose off the viewpoint kept it), after the retries;
- ``battery``: its drone left the mission on low battery before capturing it, and nobody
  captured it after;
- ``time``: the mission's time ran out before anyone captured it or gave it up; also a
  landmark nobody was trying any more when the team stopped (its drone left the mission for
  another reason and nobody took it over): no drone gave it up, the mission stopped first.

Drones give landmarks up (the strategy's codes :data:`~agent.strategy.inspection.UNREACHABLE`
and :data:`~agent.strategy.inspection.BLOCKED`, and :data:`BATTERY` here) and say so: an agent
publishes them (:class:`~agent.wire.peer.GivenUp` bit sets in its state) and every receiver
merges them with what it knows (:func:`merge_given_up`: when two drones gave the same landmark
up for different reasons, ``blocked`` wins over ``unreachable``, which wins over ``battery``: a
drone that reached a viewpoint knows more than one that did not, and one that tried knows more
than one that left). A given-up landmark captured after all counts as captured. Uncapturable
landmarks (the capture table's reasons, :data:`agent.core.inspection.REASONS`) are never
given up: they are reported apart, as ``K uncapturable (...)``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Final

import numpy as np
from numpy.typing import NDArray

from agent.strategy.inspection import BLOCKED, UNREACHABLE
from agent.wire.peer import GivenUp, GivenUpReason, pack_bits, unpack_bits

Codes = NDArray[np.int8]
Mask = NDArray[np.bool_]

#: A drone left the mission on low battery holding it (its agent gives it up as it leaves).
BATTERY: Final = 3
#: The mission's time ran out first (decided at the end, never published by a drone).
TIME: Final = 4
#: Every given-up reason by its code, in the order the end line lists them.
REASONS: Final[dict[int, str]] = {UNREACHABLE: "unreachable", BLOCKED: "blocked",
                                  BATTERY: "battery", TIME: "time"}
CODE_OF: Final[dict[str, int]] = {name: code for code, name in REASONS.items()}
#: Which reason wins when drones gave the same landmark up for different ones (higher wins).
_RANK = np.zeros(max(REASONS) + 1, dtype=np.int8)
_RANK[[BATTERY, UNREACHABLE, BLOCKED, TIME]] = [1, 2, 3, 4]
#: Ids shown per reason in a line (result.json names them all).
MOST: Final = 20


def merge_given_up(a: Codes, b: Codes) -> Codes:
    """Two per-landmark given-up code arrays (m,) merged (0: not given up): the reason that
    wins (module docstring) where both name one. Commutative, associative, idempotent."""
    return np.asarray(np.where(_RANK[b] > _RANK[a], b, a), dtype=np.int8)


def given_up_sets(codes: Codes) -> list[GivenUp]:
    """The given-up codes (m,) as published: one bit set per reason that has landmarks."""
    return [GivenUp(reason=name_of(code), landmarks=pack_bits(codes == code))
            for code in (UNREACHABLE, BLOCKED, BATTERY) if (codes == code).any()]


def name_of(code: int) -> GivenUpReason:
    """The published name of a drone's give-up code (not :data:`TIME`)."""
    if code == UNREACHABLE:
        return "unreachable"
    if code == BLOCKED:
        return "blocked"
    if code == BATTERY:
        return "battery"
    raise ValueError(f"no published given-up reason has code {code}")


def given_up_codes(sets: Sequence[GivenUp], m: int) -> Codes | None:
    """The codes (m,) of published given-up sets over m landmarks, or None if a set is not
    one for m landmarks (then nothing of it is used)."""
    out = np.zeros(m, dtype=np.int8)
    for s in sets:  # at most one set per reason
        mask = unpack_bits(s.landmarks, m)
        if mask is None:
            return None
        out = merge_given_up(out, np.where(mask, CODE_OF[s.reason], 0).astype(np.int8))
    return out


@dataclass(frozen=True)
class InspectionEnd:
    """How an inspection ended: each capturable landmark not captured with why it was given
    up (``given_up``: id → reason, ids ascending; empty: complete) and, complete, when [s]
    (None: unknown)."""

    given_up: dict[int, str] = field(default_factory=dict)
    t: float | None = None

    @property
    def complete(self) -> bool:
        """Every capturable landmark captured."""
        return not self.given_up

    def verdict(self) -> str:
        """``complete at t = X s`` or ``INCOMPLETE: G given up (a unreachable: ids; b time:
        ids)``, reasons in the order of :data:`REASONS`."""
        if self.complete:
            return "complete" if self.t is None else f"complete at t = {self.t:g} s"
        parts = []
        for reason in REASONS.values():  # four reasons
            ids = [lid for lid, why in self.given_up.items() if why == reason]
            if ids:
                shown = ", ".join(map(str, ids[:MOST])) + (" ..." if len(ids) > MOST else "")
                parts.append(f"{len(ids)} {reason}: {shown}")
        return f"INCOMPLETE: {len(self.given_up)} given up ({'; '.join(parts)})"


def inspection_end(ids: NDArray[np.int64], capturable: Mask, captured: Mask,
                   given_up: Codes | None, t: float | None = None) -> InspectionEnd:
    """The end of an inspection of landmarks ``ids`` (m,), once the team stopped or its time
    ran out: which are ``capturable`` and ``captured`` (masks (m,)), the reasons the drones
    gave landmarks up (codes (m,); None: none known) and when it completed [s] (kept only if
    it did). A capturable landmark neither captured nor given up by a drone is given up for
    ``time`` (module docstring)."""
    left = np.flatnonzero(capturable & ~captured)
    codes = np.zeros(ids.size, dtype=np.int8) if given_up is None else given_up
    why = np.where(codes[left] > 0, codes[left], TIME)
    order = np.argsort(ids[left], kind="stable")
    out = {int(ids[left[k]]): REASONS[int(why[k])] for k in order}
    return InspectionEnd(out, t if not out else None)


def captured_line(captured: int, capturable: int, spec: str,
                  uncapturable: Mapping[int, str]) -> str:
    """``captured N/M at <spec>; K uncapturable (k: reason; ...)``: what was captured of the
    capturable landmarks, and the uncapturable ones by reason."""
    line = f"captured {captured}/{capturable} at {spec}; {len(uncapturable)} uncapturable"
    if uncapturable:
        why: dict[str, list[int]] = {}
        for lid, reason in uncapturable.items():
            why.setdefault(reason, []).append(lid)
        line += " (" + "; ".join(f"{len(ids)}: {r}" for r, ids in why.items()) + ")"
    return line


def end_line(captured: str, end: InspectionEnd) -> str:
    """The whole end of an inspection in one line: :func:`captured_line`, then the verdict."""
    return f"{captured}; {end.verdict()}"
