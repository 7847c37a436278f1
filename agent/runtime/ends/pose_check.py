"""The responder's check of the pose in an offer: Algorithm 7 decides what moves by both
agents' poses, so an initiator that lies about its pose takes landmarks it does not see (a
drone with a stolen signing key could offer from beside any landmark and take it).

Before it judges any offer (Algorithm 7's, and a re-split's, a take-work's, a regroup leg's or
a revert pull's alike: an offer is an offer, whoever claims its terms), the responder compares
the offered pose with the best evidence it has of where the initiator is:

* the ground station's motion capture of that drone (``viscover/<m>/mocap/<id>``, published
  only by the ground station on the secured profile), when it is fresh (``MOCAP_FRESH_S``):
  position only (mocap gives the body attitude, not the camera direction);
* else the freshest pose the initiator published (its ``pose`` and ``state`` publications,
  :attr:`~agent.runtime.ends.membership.Membership.poses`), when fresh (``fresh_periods`` state
  periods): position and camera direction.

An agent hears the pose streams of its neighbours only
(:mod:`agent.runtime.ends.pose_interest`); a farther initiator's freshest pose is the one in
its last state. That is exact for a drone that is not moving (it publishes no pose stream
then); for one whose last state says it moves (``optimising``) the check asks for its pose
stream (:meth:`~agent.runtime.ends.pose_interest.PoseInterest.want`) and answers
``Busy("trading")``: its next offer is judged against that stream.

Without a fresh mocap the published pose must also be the initiator's own: the responder
judges against the first run of its samples it heard, or a later one (after a jump) at least
one state period old, and refuses an offer while two publishers are heard on its pose key
(``contested``,
:class:`~agent.runtime.ends.membership.PoseRuns`): a thief publishing a made-up pose under the
drone's certificate just before its offer is caught by the real drone's next sample.

An offer farther than ``pose_tolerance_m`` [m] (or ``pose_tolerance_rad`` off in direction)
is refused (``Refused("pose_mismatch")``) and counted (reject reason ``pose_mismatch``); an
offer whose initiator's pose is not known fresh is answered ``Busy("trading")`` (asked again
later; not an attack by itself, not counted). A converged initiator does not move while its
offer is out, so honest offers pass.

The mocap is listened to only where it exists (a flown drone: the runtime subscribes and
steps its samples into the core, :meth:`PoseCheck.on_mocap`), which keeps the raw payload and
decodes it only when an offer needs it.
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np

from agent.runtime.core.shared import Shared
from agent.runtime.ends.membership import Membership
from agent.runtime.ends.pose_interest import PoseInterest
from agent.wire import keys
from agent.wire.ground import MOCAP_CODEC

#: Reject reason of an offer from a pose the initiator is not at.
REASON_POSE: Final = "pose_mismatch"
#: A mocap sample this old [real s] or older is not used.
MOCAP_FRESH_S: Final = 1.0


class PoseCheck:
    """Checks offered poses against published ones and mocap (see the module docstring).

    Args:
        shared: the agent's shared state (tolerances in its config).
        members: the peers' freshest published poses.
    """

    def __init__(self, shared: Shared, members: Membership) -> None:
        self.s = shared
        self.members = members
        self._mocap: dict[str, tuple[float, bytes]] = {}  #: drone -> (mission rx [s], raw)
        members.witness = self._mocap_p  # published poses are checked against it too
        #: whose pose streams we hear (set by the core; None: every stream, as in tests)
        self.interest: PoseInterest | None = None

    def on_mocap(self, key: str, payload: bytes) -> None:
        """The ground station's mocap sample ``payload`` of the drone named by ``key``
        (kept raw, at most 1,024 drones)."""
        aid = key.rsplit("/", 1)[-1]
        if aid in self._mocap or len(self._mocap) < 1024:
            self._mocap[aid] = (self.s.now, payload)

    def _mocap_p(self, aid: str) -> np.ndarray | None:
        """The fresh mocap position [m; world ENU] of drone ``aid``, or None."""
        got = self._mocap.get(aid)
        s = self.s
        if got is None or s.now - got[0] > MOCAP_FRESH_S * s.cfg.time_scale:
            return None
        msg = MOCAP_CODEC.decode(got[1], keys.mocap_key(self.s.cfg.mission, aid))
        if msg is None or msg.drone != aid or len(msg.p) != 3:
            return None
        return np.asarray(msg.p, dtype=np.float64)

    def verdict(self, sender: str, p: tuple[float, float, float],
                v: tuple[float, float, float], now: float) -> str | None:
        """None if the offered pose (p [m], unit v) of ``sender`` agrees with the evidence;
        ``"unknown"`` if there is none fresh; else why it is refused (one line)."""
        cfg = self.s.cfg
        tol_m, tol_rad = cfg.pose_tolerance_m, cfg.pose_tolerance_rad
        offered = np.asarray(p, dtype=np.float64)
        seen = self._mocap_p(sender)
        if seen is not None:
            with np.errstate(over="ignore"):  # a huge finite offer: inf, refused
                d = float(np.linalg.norm(offered - seen))
            return None if d <= tol_m else \
                f"{sender} offers from {d:.2f} m off the ground station's mocap of it " \
                f"(tolerance {tol_m:g} m)"
        got = self.members.poses.get(sender)
        if got is None or now - got[2] > cfg.fresh_periods * cfg.state_period_s:
            return "unknown"
        if self.interest is not None and sender not in self.interest.listening:
            st = self.members.states.get(sender)
            if st is not None and st[0].phase == "optimising":  # moving: hear its stream
                self.interest.want(sender, now)
                return "unknown"
        runs = self.members.runs
        if runs.contested(sender, now):
            return f"{sender}'s pose is contested: two publishers on its pose key"
        if runs.age(sender, now) < cfg.state_period_s:
            return "unknown"  # a run this young may be a thief's: ask again
        with np.errstate(over="ignore", invalid="ignore"):  # a huge finite offer: inf, refused
            d = float(np.linalg.norm(offered - got[0]))
            cos = float(np.dot(np.asarray(v, dtype=np.float64), got[1]) /
                        max(1e-12, float(np.linalg.norm(v)) * float(np.linalg.norm(got[1]))))
        ang = math.acos(max(-1.0, min(1.0, cos)))
        if d <= tol_m and ang <= tol_rad:
            return None
        return (f"{sender} offers from {d:.2f} m and {math.degrees(ang):.0f} deg off the pose "
                f"it publishes (tolerance {tol_m:g} m, {math.degrees(tol_rad):.0f} deg)")
