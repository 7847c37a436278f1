"""Helpers of the simulated-vehicle equipment tests (camera, gimbal, fence, battery, EKF,
missions in AUTO): commands and the mission protocol over a raw pymavlink client on the
:class:`tests.vehicle_harness.Harness`, mission items from a QGroundControl ``.plan``, and a
MAVSDK session (``mavsdk_grpc``'s own ``mavsdk_server``) against a fleet on the wall clock."""

from __future__ import annotations

import asyncio
import math
import socket
from collections.abc import Awaitable, Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from agent.clock import WallClock
from agent.flight.frames import euler_from_quat
from agent.wire.mavlink import mavlink
from groundstation.vehicle.conventions import local_ne
from groundstation.vehicle.fleet import SimFleet
from groundstation.vehicle.params import VehicleParams
from tests.vehicle_harness import Harness

M = mavlink
NAN = math.nan
T = TypeVar("T")
Array = NDArray[np.float64]


def conf(**params: float) -> dict[str, float]:
    """Autopilot parameters by name (``VehicleParams.params``)."""
    return dict(params)


def hello(h: Harness) -> Harness:
    """A ground station's HEARTBEAT: the vehicle streams to peers it has heard from."""
    h.client.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    h.run(0.02)
    return h


def command(h: Harness, cmd: int, *params: float, target: tuple[int, int] = (1, 1),
            sim_s: float = 0.5) -> Any:
    """COMMAND_LONG (unused params NaN, as MAVSDK sends them); its COMMAND_ACK (None if none
    came within ``sim_s`` [s sim])."""
    p = [*params, NAN, NAN, NAN, NAN, NAN, NAN, NAN][:7]
    h.client.mav.command_long_send(*target, cmd, 0, *p)
    return h.wait_for("COMMAND_ACK", lambda m: m.command == cmd, sim_s=sim_s)


def result(h: Harness, cmd: int, *params: float, target: tuple[int, int] = (1, 1)) -> int | None:
    """The MAV_RESULT of :func:`command` (None: no ACK)."""
    ack = command(h, cmd, *params, target=target)
    return None if ack is None else int(ack.result)


def airborne(h: Harness, alt: float = 3.0, check: bool = True) -> None:
    """Arm in GUIDED / OFFBOARD on forwarded mocap and climb to ``alt`` [m] on a level
    attitude set-point stream whose thrust is a small altitude loop around 0.5 (ArduCopter:
    climb rate 0; PX4: the default vehicle's hover thrust), which then holds it (``check``:
    assert it got there)."""
    px4 = h.quad.flavour.name == "px4"

    def feed() -> None:
        h.vision()
        v_down = float(h.fleet.v[0, 2])
        h.attitude(min(max(0.5 + 0.15 * (alt - h.altitude()) + 0.2 * v_down, 0.3), 0.8))

    h.every = feed
    h.run(0.3)
    assert h.set_mode(6 if px4 else 4) == M.MAV_RESULT_ACCEPTED
    assert h.arm() == M.MAV_RESULT_ACCEPTED
    for _ in range(400):
        if abs(h.altitude() - alt) < 0.1 and abs(float(h.fleet.v[0, 2])) < 0.1:
            break
        h.run(0.05)
    assert not check or abs(h.altitude() - alt) < 0.2


@dataclass(frozen=True)
class MissionItem:
    """One MISSION_ITEM_INT: frame, command, param1..param4, x, y (degE7 for global frames,
    integers for MAV_FRAME_MISSION), z."""

    frame: int
    command: int
    params: tuple[float, float, float, float]
    x: int = 0
    y: int = 0
    z: float = 0.0


def upload_mission(h: Harness, items: Sequence[MissionItem],
                   mission_type: int = M.MAV_MISSION_TYPE_MISSION,
                   sim_s: float = 5.0) -> int | None:
    """The mission protocol's upload over pymavlink (MISSION_COUNT, then each
    MISSION_ITEM_INT the vehicle asks for); the final MISSION_ACK's type (None: none came)."""
    h.client.mav.mission_count_send(h.quad.sysid, 1, len(items), mission_type)
    end = h.clock.now() + sim_s
    while h.clock.now() < end:
        h.run(0.01)
        for req in h.of("MISSION_REQUEST_INT"):
            it = items[req.seq]
            h.client.mav.mission_item_int_send(h.quad.sysid, 1, req.seq, it.frame, it.command, 0,
                                               1, *it.params, it.x, it.y, it.z, mission_type)
        acks = h.of("MISSION_ACK")
        if acks:
            return int(acks[-1].type)
    return None


def plan_mission(plan: dict[str, Any]) -> list[MissionItem]:
    """The mission items of a QGroundControl ``.plan`` as MAVSDK's
    ``import_qgroundcontrol_mission`` makes them: null params NaN, lat/lon degE7 for global
    frames, params 5 and 6 as integers otherwise; for an ArduPilot plan (firmwareType 3) the
    planned home position first (item 0, MAV_FRAME_GLOBAL, altitude AMSL)."""
    mission = plan["mission"]
    out: list[MissionItem] = []
    if mission["firmwareType"] == 3:
        lat, lon, alt = mission["plannedHomePosition"]
        out.append(MissionItem(M.MAV_FRAME_GLOBAL, M.MAV_CMD_NAV_WAYPOINT, (0.0, 0.0, 0.0, 0.0),
                               round(lat * 1e7), round(lon * 1e7), float(alt)))
    for item in mission["items"]:
        p = [NAN if v is None else float(v) for v in item["params"]]
        frame = int(item["frame"])
        if frame == M.MAV_FRAME_MISSION:
            x, y = (0 if math.isnan(v) else int(v) for v in p[4:6])
        else:
            x, y = round(p[4] * 1e7), round(p[5] * 1e7)
        out.append(MissionItem(frame, int(item["command"]), (p[0], p[1], p[2], p[3]), x, y,
                               p[6]))
    return out


@dataclass
class Flown:
    """What a flight showed on the wire: MISSION_ITEM_REACHED (seq, the true position [m;
    NED] then), the captures, STATUSTEXTs, MISSION_CURRENTs, the true path (t, p, v)."""

    reached: list[tuple[int, Array]] = field(default_factory=list)
    shots: list[Any] = field(default_factory=list)
    shot_pitch: list[float] = field(default_factory=list)  #: gimbal pitch [deg] at each shot
    #: gimbal yaw [deg] at each shot, as its device reports it (vehicle frame)
    shot_gimbal_yaw: list[float] = field(default_factory=list)
    texts: list[str] = field(default_factory=list)
    current: list[Any] = field(default_factory=list)
    path: list[tuple[float, Array, Array]] = field(default_factory=list)

    @property
    def seqs(self) -> list[int]:
        return [s for s, _ in self.reached]

    def where(self, seq: int) -> Array:
        return next(p for s, p in self.reached if s == seq)


def fly(h: Harness, sim_s: float, done: Callable[[Harness], bool]) -> Flown:
    """Run until ``done`` (or ``sim_s`` [s sim]), recording what :class:`Flown` holds."""
    out = Flown()
    pitch = gimbal_yaw = math.nan  # the gimbal device's last reported attitude [deg]
    end = h.clock.now() + sim_s
    while h.clock.now() < end and not done(h):
        h.run(0.02)
        out.path.append((h.clock.now(), h.fleet.p[0].copy(), h.fleet.v[0].copy()))
        for m in list(h.inbox):
            kind = m.get_type()
            if kind == "GIMBAL_DEVICE_ATTITUDE_STATUS":
                _r, pitch_r, yaw_r = euler_from_quat(np.array(m.q, dtype=np.float64))
                pitch, gimbal_yaw = math.degrees(pitch_r), math.degrees(yaw_r)
            elif kind == "MISSION_ITEM_REACHED":
                out.reached.append((int(m.seq), h.fleet.p[0].copy()))
            elif kind in ("CAMERA_FEEDBACK", "CAMERA_IMAGE_CAPTURED"):
                out.shots.append(m)
                out.shot_pitch.append(pitch)
                out.shot_gimbal_yaw.append(gimbal_yaw)
            elif kind == "STATUSTEXT":
                out.texts.append(str(m.text))
            elif kind == "MISSION_CURRENT":
                out.current.append(m)
        h.inbox.clear()
    return out


def ned(h: Harness, lat_e7: int, lon_e7: int, alt_mm_msl: int) -> Array:
    """A reported position as local NED [m] from the vehicle's EKF origin."""
    n, e = local_ne(h.quad.origin, lat_e7, lon_e7)
    return np.array([float(n), float(e), h.quad.origin[2] - alt_mm_msl / 1000.0])


def run_sdk(params: VehicleParams, body: Callable[[Any, SimFleet], Awaitable[T]],
            timeout_s: float = 60.0) -> T:
    """Run ``body(system, fleet)`` with MAVSDK connected to one simulated vehicle (wall
    clock); the server and the fleet are closed afterwards."""
    mavsdk = __import__("mavsdk_grpc")
    with _fleet(params) as fleet:
        async def main() -> T:
            system = mavsdk.System(port=_free_port(socket.SOCK_STREAM))
            try:
                await asyncio.wait_for(system.connect(
                    system_address=f"udpout://127.0.0.1:{fleet.quads[0].port}"), 30.0)
                return await asyncio.wait_for(body(system, fleet), timeout_s)
            finally:
                system._stop_mavsdk_server()

        return asyncio.run(main())


async def first(stream: Any, pred: Callable[[Any], bool] = lambda _x: True,
                timeout_s: float = 15.0) -> Any:
    """The first item of an async MAVSDK stream that satisfies ``pred``."""
    async def get() -> Any:
        async for item in stream:
            if pred(item):
                return item
        raise AssertionError("stream ended")

    return await asyncio.wait_for(get(), timeout_s)


@contextmanager
def _fleet(params: VehicleParams) -> Iterator[SimFleet]:
    fleet = SimFleet(["d0"], WallClock(), params)
    try:
        yield fleet.start()
    finally:
        fleet.close()


def _free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
