"""Phase 4 of a flying agent: back to where it took off. The launch point is read from the
pose source before take-off (:func:`launch_point`); :func:`fly_home` flies there at the
current height round the structure and the other drones, then holds until still."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agent.clock import Clock
from agent.config.scenario import Scenario
from agent.core.homing import detour_waypoints, homing_velocity
from agent.flight.vehicle_pose import MavlinkPoseSource, MocapNeighbours

Array = NDArray[np.float64]

#: A waypoint of the way home round the structure counts as reached this close [m].
WAYPOINT_M = 0.3


def launch_point(sample: Any, p0: Array) -> Array:
    """Where the drone took off [m; world ENU]: its mocap position while still on the ground,
    or (already airborne, e.g. after a restart) the ground below its initial scenario pose."""
    if sample is not None and float(sample.p[2]) < 0.3:
        return np.array(sample.p, dtype=np.float64)
    return np.array([p0[0], p0[1], 0.0])


def fly_home(source: MavlinkPoseSource, neighbours: MocapNeighbours, home: Array,
             sc: Scenario, clock: Clock, timeout_s: float, arrive_m: float = 0.1,
             still_mps: float = 0.05) -> bool:
    """Phase 4: fly at the current height to above the launch point ``home`` [m; world ENU]
    round the landmarks' bounding box (:func:`agent.core.homing.detour_waypoints`) with
    :func:`agent.core.homing.homing_velocity` (walls, R_s from the other drones' mocap
    positions, R_s/2 from the box), then hold until the vehicle is still
    (the autopilot's LAND would carry any residual speed sideways). True once within
    ``arrive_m`` metres (horizontally) and slower than ``still_mps``; False after
    ``timeout_s`` [s sim]."""
    p = source.current()[0]
    target = np.array([home[0], home[1], p[2]])
    structure = (sc.q.min(axis=0), sc.q.max(axis=0))  # the landmarks' bounding box
    prm = sc.params
    route = list(detour_waypoints(p, target, structure, 0.5 * prm.r_s, 0.5 * prm.r_s + prm.d_w))
    dt = prm.dt
    t_end = clock.now() + timeout_s
    holding = False
    while clock.now() < t_end and source.driver.released is None:
        sample = source.pose()  # mocap: position p, velocity vel
        if sample is None:  # no mocap yet (the driver's failsafe watches its age)
            time.sleep(clock.wall(dt))
            continue
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
