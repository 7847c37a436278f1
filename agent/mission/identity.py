"""One agent id, one process: two processes publishing states under one id, told apart by
their state streams (see :class:`IdentityWatch`; used by :mod:`agent.mission.observer`)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class _Stream:
    """One process's states under an agent id: incarnation, wall times first/last heard [s]
    and the mission time t [s] of its recent sequence numbers."""

    number: int  #: serial number among every stream seen
    incarnation: int
    first: float
    last: float
    times: dict[int, float] = field(default_factory=dict)

    def fits(self, seq: int, t: float, window: int) -> bool:
        """Whether (seq, mission t [s]) continues this stream: near its newest, t monotone."""
        if not self.times or seq <= max(self.times) - window:
            return False
        if seq in self.times:
            return abs(self.times[seq] - t) <= _T_EPS
        below = [s for s in self.times if s < seq]
        above = [s for s in self.times if s > seq]
        return (not below or t >= self.times[max(below)] - _T_EPS) and \
            (not above or t <= self.times[min(above)] + _T_EPS)

    def add(self, seq: int, t: float, now: float, window: int) -> None:
        """Record (seq, t) heard at wall time ``now`` [s]; keep the newest ``window`` seqs."""
        self.times[seq] = t
        self.last = max(self.last, now)
        if len(self.times) > window:
            del self.times[min(self.times)]


#: Mission-time tolerance [s] when matching a state to a stream (one process's t is exact).
_T_EPS = 1e-6


class IdentityWatch:
    """Two processes publishing states under one agent id (see the module docstring)."""

    def __init__(self, grace_s: float = 2.0, window: int = 64, max_streams: int = 8) -> None:
        self.grace_s, self.window, self.max_streams = grace_s, window, max_streams
        self.streams: dict[str, list[_Stream]] = {}
        self._reported: set[tuple[str, int, int]] = set()
        self._count = 0

    def add(self, agent: str, incarnation: int, seq: int, t: float, now: float) -> list[str]:
        """Record a state heard at wall time ``now`` [s]; violations: a second process."""
        streams = self.streams.setdefault(agent, [])
        fit = [s for s in streams if s.incarnation == incarnation
               and s.fits(seq, t, self.window)]
        if fit:
            mine = min(fit, key=lambda s: abs(seq - max(s.times)))
        else:
            self._count += 1
            mine = _Stream(self._count, incarnation, now, now)
            streams.append(mine)
            if len(streams) > self.max_streams:
                streams.remove(min(streams, key=lambda s: s.last))
        mine.add(seq, t, now, self.window)
        out = []
        for other in streams:
            overlap = min(mine.last, other.last) - max(mine.first, other.first)
            key = (agent, min(mine.number, other.number), max(mine.number, other.number))
            if other is mine or overlap <= self.grace_s or key in self._reported:
                continue
            self._reported.add(key)
            out.append(f"agent {agent}: two processes claim this id (incarnations "
                       f"{other.incarnation} and {mine.incarnation} both publishing for "
                       f"{overlap:.1f} s)")
        return out
