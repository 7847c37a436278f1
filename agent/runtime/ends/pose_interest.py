"""Whose pose streams an agent listens to: its neighbours, not the whole team, so that what
a drone's link carries does not grow with the team.

A drone publishes its pose at every planner step while it moves (``viscover/<m>/pose/<id>``)
and its state, which carries the same position, once a state period. The ground station,
the recorder and the ROS 2 bridge hear every pose stream; an agent needs a peer's pose at
that rate only to avoid it (section 4.3) and to judge its offers while it moves. So an agent
subscribes to the pose keys of:

* its **neighbours**: the peers whose last known position [m; world ENU] (from a pose or a
  state; at first the scenario's start) lies within :meth:`PoseInterest.radius` of its own,
  until they are 1.5 times as far (hysteresis, so that a peer on the boundary does not make
  it subscribe and undeclare every tick);
* the peers it was **asked about**: a moving initiator whose offer the pose check could not
  judge from its states alone (:meth:`PoseInterest.want`, for ``fresh_periods`` state
  periods).

The radius: the safety and worry distances, plus how far two drones closing at full speed
(``2·p_lim``) travel in two state periods (the position of a peer not listened to is at
most one state period old, and the set is updated once a tick), plus 2 m, and at least
:data:`NEAR_MIN_M`. Everything else is heard through the states; the trade protocol, the
completion rule and the capture evidence read nothing else.

Pure: positions and mission time come in, the set goes out as a
:class:`~agent.runtime.core.events.Listen` effect when it changes.
"""

from __future__ import annotations

from typing import Final

import numpy as np

from agent.runtime.core.shared import Shared
from agent.runtime.ends.membership import Membership

#: [m] the neighbourhood radius is never smaller than this
NEAR_MIN_M: Final = 10.0
#: leave the neighbourhood only beyond this many times the radius
HYSTERESIS: Final = 1.5


class PoseInterest:
    """The set of peers whose pose streams to hear (see the module docstring)."""

    def __init__(self, shared: Shared, members: Membership) -> None:
        self.s = shared
        self.members = members
        self.listening: frozenset[str] = frozenset()  #: the set last handed out
        self.wanted: dict[str, float] = {}  #: peer -> mission time [s] asked for until

    def radius(self) -> float:
        """The neighbourhood radius [m] (module docstring)."""
        prm, cfg = self.s.sc.params, self.s.cfg
        closing = 2.0 * prm.p_lim * 2.0 * cfg.state_period_s
        return max(NEAR_MIN_M, prm.r_s + prm.d_w + closing + 2.0)

    def want(self, aid: str, now: float) -> None:
        """Hear ``aid``'s poses for the next ``fresh_periods`` state periods (an offer of a
        moving initiator to judge)."""
        cfg = self.s.cfg
        if aid in self.wanted or len(self.wanted) < 64:
            self.wanted[aid] = now + cfg.fresh_periods * cfg.state_period_s

    def update(self, me: np.ndarray, now: float) -> frozenset[str] | None:
        """The peers to hear now, our position ``me`` [m; world ENU]: the new set if it
        changed since the last one handed out, else None."""
        others = self.members.others_pos
        r = self.radius()
        near = set()
        if others:
            ids = list(others)
            d = np.linalg.norm(np.asarray([others[a] for a in ids], dtype=np.float64)
                               - me[None, :], axis=1)
            near = {a for a, dist in zip(ids, d.tolist(), strict=True)
                    if dist <= r or (a in self.listening and dist <= HYSTERESIS * r)}
        self.wanted = {a: t for a, t in self.wanted.items() if t > now}
        got = frozenset(near | set(self.wanted))
        if got == self.listening:
            return None
        self.listening = got
        return got
