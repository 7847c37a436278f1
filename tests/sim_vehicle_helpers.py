"""Helpers of the simulated-vehicle equipment tests (camera, gimbal, fence, battery, EKF):
commands over a raw pymavlink client on the :class:`tests.vehicle_harness.Harness`, and a
MAVSDK session (``mavsdk_grpc``'s own ``mavsdk_server``) against a fleet on the wall clock."""

from __future__ import annotations

import asyncio
import math
import socket
from collections.abc import Awaitable, Callable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

from agent.clock import WallClock
from agent.wire.mavlink import mavlink
from groundstation.vehicle.fleet import SimFleet
from groundstation.vehicle.params import VehicleParams
from tests.vehicle_harness import Harness

M = mavlink
NAN = math.nan
T = TypeVar("T")


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
    px4 = h.quad.px4

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
