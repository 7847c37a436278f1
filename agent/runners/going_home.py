"""Phase 4 of a flying agent: back to where it took off. The launch point is read from the
pose source before take-off (:func:`launch_point`); :func:`fly_home` flies there at the
current height round the structure and the other drones, then holds until still.

Where the other drones are: indoors the ground station's mocap of each
(:class:`~agent.flight.vehicle_pose.MocapNeighbours`); outdoors, where drones fly on their
autopilots' pose and no ground station tracks them, what the agents publish themselves
(:class:`PublishedNeighbours`: their poses and states). Either way a drone on its way home
keeps saying its own pose on its pose key (:meth:`PublishedNeighbours.say`), so the others,
going home too, keep R_s from it.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from agent.clock import Clock
from agent.config.scenario import Scenario
from agent.core.homing import detour_waypoints, homing_velocity
from agent.flight.vehicle_pose import MavlinkPoseSource
from agent.net.contract import Declared, Transport
from agent.net.rejects import LockedRejectCounter
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.peer import AgentState, Pose, Publication

Array = NDArray[np.float64]


class Neighbours(Protocol):
    """Where the other drones of the mission are."""

    def positions(self, max_age_s: float = 1.0) -> Array:
        """Positions [m; world ENU] (n, 3) of the other drones heard within ``max_age_s``
        wall seconds."""
        ...


class PublishedNeighbours:
    """The other drones' positions from what their agents publish (``viscover/<m>/pose/*``
    and ``state/*``: each one's own pose estimate, the autopilot's outdoors), and this drone's
    pose said on its own pose key (:meth:`say`). A publication that does not decode, is on
    another agent's key or is not a pose or a state is counted in ``rejects``."""

    def __init__(self, transport: Transport, mission: str, me: str, seq0: int = 0) -> None:
        self.tp, self.mission, self.me = transport, mission, me
        self.seq = seq0  #: the last pose sequence number said (continue the runtime's)
        self.rejects = LockedRejectCounter()
        self._codec: Codec[Publication] = Codec(Publication, counter=self.rejects)
        self._lock = threading.Lock()
        self._latest: dict[str, tuple[float, Array]] = {}  # drone -> (wall rx [s], p [m])
        self._subs: list[Declared] = [
            transport.subscribe(keys.all_agents(mission, kind), self._on_sample)
            for kind in ("pose", "state")]

    def _on_sample(self, key: str, payload: bytes) -> None:
        msg = self._codec.decode(payload, key)
        if msg is None:
            return
        if not isinstance(msg, (Pose, AgentState)) or keys.try_agent_of(key) != msg.sender:
            self._codec.reject("impossible", key, "not a pose or state of the key's agent")
            return
        if msg.sender == self.me:
            return
        with self._lock:
            self._latest[msg.sender] = (time.monotonic(), np.array(msg.p, dtype=np.float64))

    def positions(self, max_age_s: float = 1.0) -> Array:
        """Positions [m; world ENU] (n, 3) of the other drones heard within ``max_age_s``
        wall seconds."""
        now = time.monotonic()
        with self._lock:
            fresh = [p for rx, p in self._latest.values() if now - rx <= max_age_s]
        return np.array(fresh).reshape(-1, 3)

    def say(self, p: Array, v: Array, t: float) -> None:
        """Publish this drone's pose: position p [m; world ENU], unit camera direction v, at
        mission time t [s]."""
        self.seq += 1
        msg = Pose(sender=self.me, seq=self.seq, t=float(t),
                   p=(float(p[0]), float(p[1]), float(p[2])),
                   v=(float(v[0]), float(v[1]), float(v[2])))
        try:
            self.tp.publish(keys.pose_key(self.mission, self.me), self._codec.encode(msg))
        except RuntimeError:  # the transport closed under us (shutdown)
            pass

    def close(self) -> None:
        """Unsubscribe."""
        for s in self._subs:
            s.undeclare()

#: A waypoint of the way home round the structure counts as reached this close [m].
WAYPOINT_M = 0.3


def launch_point(sample: Any, p0: Array) -> Array:
    """Where the drone took off [m; world ENU]: its mocap position while still on the ground,
    or (already airborne, e.g. after a restart) the ground below its initial scenario pose."""
    if sample is not None and float(sample.p[2]) < 0.3:
        return np.array(sample.p, dtype=np.float64)
    return np.array([p0[0], p0[1], 0.0])


def fly_home(source: MavlinkPoseSource, neighbours: Neighbours, home: Array,
             sc: Scenario, clock: Clock, timeout_s: float, arrive_m: float = 0.1,
             still_mps: float = 0.05,
             say: Callable[[Array, Array, float], None] | None = None) -> bool:
    """Phase 4: fly at the current height to above the launch point ``home`` [m; world ENU]
    round the landmarks' bounding box (:func:`agent.core.homing.detour_waypoints`) with
    :func:`agent.core.homing.homing_velocity` (walls, R_s from the ``neighbours``' positions,
    R_s/2 from the box), then hold until the vehicle is still
    (the autopilot's LAND would carry any residual speed sideways); ``say`` (p, v, t) is
    told the pose every step. True once within ``arrive_m`` metres (horizontally) and slower
    than ``still_mps``; False after ``timeout_s`` [s sim]."""
    p = source.current()[0]
    target = np.array([home[0], home[1], p[2]])
    structure = (sc.q.min(axis=0), sc.q.max(axis=0))  # the landmarks' bounding box
    prm = sc.params
    route = list(detour_waypoints(p, target, structure, 0.5 * prm.r_s, 0.5 * prm.r_s + prm.d_w))
    dt = prm.dt
    t_end = clock.now() + timeout_s
    holding = False
    while clock.now() < t_end and source.driver.released is None:
        sample = source.pose()  # mocap (or the autopilot's): position p, velocity vel
        if sample is None:  # no pose yet (the driver's failsafe watches its age)
            time.sleep(clock.wall(dt))
            continue
        if say is not None:
            say(*source.current())
        if len(route) > 1 and float(np.hypot(*(route[0] - sample.p)[:2])) <= WAYPOINT_M:
            route.pop(0)  # round a corner of the structure: on to the next waypoint
        near = float(np.hypot(*(target - sample.p)[:2])) <= arrive_m
        if near and not holding:
            source.hold(target)
            holding = True
        if holding:
            if near and float(np.linalg.norm(sample.vel)) <= still_mps:
                return True
        else:
            vel = homing_velocity(sample.p, route[0], prm, sc.space,
                                  neighbours.positions(), structure=structure)
            if np.any(vel):
                source.command(vel, np.zeros(3), dt)
            else:
                source.hold()  # blocked for now: hold and look again
        time.sleep(clock.wall(dt))
    source.hold()
    return False
