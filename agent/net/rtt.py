"""Retransmission timing from measured round trips, as TCP times its own (RFC 6298): the
timeout of a query, the delay before one more copy of an unanswered one goes out, and the
send schedule of one try of a request. Pure: no clock, no I/O (times are given in)."""

from __future__ import annotations

import math


class RttEstimator:
    """Retransmission timeout [real s] from measured round trips (RFC 6298): the smoothed
    round trip SRTT and its mean deviation RTTVAR (gains 1/8 and 1/4; the first sample R sets
    SRTT = R, RTTVAR = R / 2), RTO = SRTT + 4 RTTVAR kept within [``min_s``, ``max_s``];
    ``initial_s`` (within the same bounds) until the first sample. The hedge delay, after
    which one more copy of an unanswered request goes out, is SRTT + 2 RTTVAR (a reply later
    than that is rare, and a late one is still taken). ``loss``: the smoothed fraction of
    copies that got no reply; while it is high each copy goes out ``width`` times at once."""

    ALPHA = 0.125
    BETA = 0.25
    K = 4.0
    K_HEDGE = 2.0
    LOSS_GAIN = 1.0 / 16.0

    def __init__(self, initial_s: float, min_s: float, max_s: float) -> None:
        if not 0.0 < min_s <= max_s:
            raise ValueError(f"need 0 < min_s <= max_s, got {min_s}, {max_s}")
        self.initial_s, self.min_s, self.max_s = initial_s, min_s, max_s
        self.srtt: float | None = None  #: smoothed round trip [s] (None: no sample yet)
        self.rttvar = 0.0  #: mean deviation of the round trip [s]
        self.samples = 0
        self.loss = 0.0  #: smoothed fraction of copies without a reply

    def copies_lost(self, sent: int, answered: int | None) -> None:
        """Learn from one try: ``sent`` copies, the first reply from copy ``answered`` (None:
        none); the copies sent before it count as lost, it as delivered."""
        for _ in range(sent if answered is None else min(answered, sent)):
            self.loss += self.LOSS_GAIN * (1.0 - self.loss)
        if answered is not None:
            self.loss -= self.LOSS_GAIN * self.loss

    @property
    def width(self) -> int:
        """Copies sent at once (1; 2 from 25 % of the copies lost, 3 from 60 %: a copy is
        lost when its query or its reply is)."""
        return 1 + (self.loss >= 0.25) + (self.loss >= 0.6)

    def sample(self, rtt_s: float) -> None:
        """Take one measured round trip [s] (negative or not finite: ignored)."""
        if not (math.isfinite(rtt_s) and rtt_s >= 0.0):
            return
        if self.srtt is None:
            self.srtt, self.rttvar = rtt_s, rtt_s / 2.0
        else:
            self.rttvar += self.BETA * (abs(self.srtt - rtt_s) - self.rttvar)
            self.srtt += self.ALPHA * (rtt_s - self.srtt)
        self.samples += 1

    def _bounded(self, k: float) -> float:
        raw = self.initial_s if self.srtt is None else self.srtt + k * self.rttvar
        return min(self.max_s, max(self.min_s, raw))

    @property
    def rto(self) -> float:
        """The retransmission timeout now [s]."""
        return self._bounded(self.K)

    @property
    def hedge(self) -> float:
        """The hedge delay now [s] (at most the RTO)."""
        return self._bounded(self.K_HEDGE)

    def schedule(self, copies: int, failures: int) -> tuple[list[float], float]:
        """One try of a request after ``failures`` consecutive tries without a reply: the
        send offsets of its copies [s] and how long it waits in all [s]. Copies go out one
        hedge delay apart (``width`` at a time) and the try waits one RTO after the last: with
        measured round trips ``copies`` of them at first, and per try without a reply half as
        many (rounded up) with both delays doubled (up to ``max_s``), so that an unreachable
        partner gets one copy per ``max_s`` soon; without a measured round trip up to three
        copies spread over ``initial_s`` (within the bounds), the time the try waits."""
        if self.srtt is None:
            n = min(3, max(1, copies))
            return [k * self.rto / n for k in range(n)], self.rto
        f = min(max(0, failures), 32)
        n = max(1, -(-max(1, copies) // 2 ** f))
        gap = min(self.max_s, self.hedge * 2.0 ** f)
        offsets = [k * gap for k in range(n) for _ in range(self.width)]
        return offsets, (n - 1) * gap + min(self.max_s, self.rto * 2.0 ** f)
