"""Trading of landmarks between two agents (thesis section 4.5, Algorithm 7).

Pure functions: who should own each landmark after a one-to-one trade, and the partner-list
rules an agent follows when it looks for someone to trade with.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from agent.core.vision import DistanceTerm, Landmarks, as_distance_term, per_landmark_cols

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]


@dataclass(frozen=True)
class TradeOutcome:
    """Algorithm 7 result: which of A's landmarks go to B and which of B's go to A."""

    a_to_b: Mask  #: over A's landmarks (m_A,)
    b_to_a: Mask  #: over B's landmarks (m_B,)
    gain: float  #: increase of vis_A + vis_B (eq. 4.13), > 0 iff the trade is successful

    @property
    def success(self) -> bool:
        """Section 4.5: a trade succeeds when at least one landmark changes owner."""
        return bool(self.a_to_b.any() or self.b_to_a.any())


def trade_landmarks(
    p_a: Array, v_a: Array, q_a: Array, u_a: Array,
    p_b: Array, v_b: Array, q_b: Array, u_b: Array,
    d_opt: float | DistanceTerm,
    clear_a: Mask | None = None, clear_b: Mask | None = None,
) -> TradeOutcome:
    """Algorithm 7: move each landmark to the agent that sees it strictly better (ties stay).

    ``clear_a`` / ``clear_b`` (optional, over A's then B's landmarks, (m_A + m_B,)): whether
    each landmark's line of sight from A's / B's camera is unoccluded; an occluded landmark
    counts 0 for that agent (occlusion-aware Algorithm 7)."""
    lm = Landmarks.of(np.concatenate((q_a, q_b)), np.concatenate((u_a, u_b)))
    return trade_stacked(p_a, v_a, p_b, v_b, lm, q_a.shape[0], d_opt, clear_a, clear_b)


def trade_stacked(
    p_a: Array, v_a: Array, p_b: Array, v_b: Array, lm: Landmarks, m_a: int,
    d_opt: float | DistanceTerm,
    clear_a: Mask | None = None, clear_b: Mask | None = None,
) -> TradeOutcome:
    """Algorithm 7 over one stacked landmark set: columns [0, m_a) are A's, the rest B's;
    occluded landmarks (``clear_*`` False) count 0 for that agent."""
    term = as_distance_term(d_opt)
    by_a, by_b = per_landmark_cols(p_a, v_a, lm, term), per_landmark_cols(p_b, v_b, lm, term)
    if clear_a is not None:
        by_a = np.where(clear_a, by_a, 0.0)
    if clear_b is not None:
        by_b = np.where(clear_b, by_b, 0.0)
    a_own, a_on_b = by_a[:m_a], by_a[m_a:]
    b_on_a, b_own = by_b[:m_a], by_b[m_a:]
    a_to_b = b_on_a > a_own
    b_to_a = a_on_b > b_own
    gain = float((b_on_a - a_own)[a_to_b].sum() + (a_on_b - b_own)[b_to_a].sum())
    return TradeOutcome(a_to_b=a_to_b, b_to_a=b_to_a, gain=gain)


@dataclass
class PartnerList:
    """Section 4.5: the ordered list of agents this agent may still try to trade with."""

    me: str
    everyone: tuple[str, ...]
    pending: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        if not self.pending:
            self.reset()

    def reset(self, everyone: Iterable[str] | None = None) -> None:
        """After a successful trade (or a membership change): all other agents, in order."""
        if everyone is not None:
            self.everyone = tuple(everyone)
        self.pending = [a for a in self.everyone if a != self.me]

    def next(self) -> str | None:
        """The partner to try now, or None: the agent waits passively."""
        return self.pending[0] if self.pending else None

    def drop(self, partner: str) -> None:
        """The partner was busy, unreachable, or the trade failed: remove it."""
        if partner in self.pending:
            self.pending.remove(partner)

    def forget(self, partner: str) -> None:
        """The partner left the mission (liveliness lost): remove it for good."""
        self.everyone = tuple(a for a in self.everyone if a != partner)
        self.drop(partner)
