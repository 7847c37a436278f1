"""A deterministic harness for the simulated vehicle: a manual clock stepped by the test and
a raw pymavlink client (a ground station or a companion) on loopback UDP."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from agent.clock import ManualClock
from agent.flight.frames import quat_from_euler
from agent.wire.mavlink import mavlink, mavutil
from groundstation.vehicle.fleet import SimFleet
from groundstation.vehicle.params import VehicleParams

LEVEL_Q = [float(a) for a in quat_from_euler(0.0, 0.0, 0.0)]


class Harness:
    """One or more simulated vehicles on a :class:`ManualClock`, one MAVLink client."""

    def __init__(self, params: VehicleParams | list[VehicleParams], n: int = 1,
                 source_system: int = 255, source_component: int = 190,
                 start: np.ndarray | None = None, seed: int = 0) -> None:
        self.clock = ManualClock()
        self.fleet = SimFleet([f"d{i}" for i in range(n)], self.clock, params, start=start,
                              seed=seed)
        self.quad = self.fleet.quads[0]
        self.client = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{self.quad.port}", source_system=source_system,
            source_component=source_component)
        self.inbox: list[Any] = []
        self.every: Callable[[], None] | None = None

    def close(self) -> None:
        self.client.close()
        self.fleet.close()

    def __enter__(self) -> Harness:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def drain(self) -> None:
        """Collect what the vehicle sent to the client."""
        while True:
            m = self.client.recv_match(blocking=False)
            if m is None:
                return
            if m.get_type() != "BAD_DATA":
                self.inbox.append(m)

    def run(self, dt: float, step: float = 0.01) -> None:
        """Advance the simulation dt seconds in ticks of ``step``, calling ``every`` first."""
        end = self.clock.now() + dt - 1e-9
        while self.clock.now() < end:
            if self.every is not None:
                self.every()
            time.sleep(0.0002)  # let loopback datagrams land
            self.clock.advance(step)
            self.fleet.tick()
            self.drain()

    def wait_for(self, kind: str, pred: Callable[[Any], bool] = lambda m: True,
                 sim_s: float = 1.0) -> Any:
        """Run until a message of ``kind`` matching ``pred`` arrives (None if none)."""
        end = self.clock.now() + sim_s
        while self.clock.now() < end:
            for m in self.inbox:
                if m.get_type() == kind and pred(m):
                    self.inbox.remove(m)
                    return m
            self.run(0.01)
        return None

    def of(self, kind: str) -> list[Any]:
        """Received messages of ``kind`` (removed from the inbox)."""
        got = [m for m in self.inbox if m.get_type() == kind]
        self.inbox = [m for m in self.inbox if m.get_type() != kind]
        return got

    def command(self, cmd: int, *params: float) -> int:
        """COMMAND_LONG to the vehicle; its COMMAND_ACK result."""
        p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        self.client.mav.command_long_send(self.quad.sysid, 1, cmd, 0, *p)
        ack = self.wait_for("COMMAND_ACK", lambda m: m.command == cmd)
        assert ack is not None, f"no COMMAND_ACK for {cmd}"
        return int(ack.result)

    def set_mode(self, custom: int, sub: int = 0) -> int:
        return self.command(mavlink.MAV_CMD_DO_SET_MODE,
                            mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom, sub)

    def arm(self, on: bool = True, force: bool = False) -> int:
        return self.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0 if on else 0.0,
                            21196.0 if force else 0.0)

    def attitude(self, thrust: float, q: list[float] | None = None, mask: int = 7) -> None:
        """One SET_ATTITUDE_TARGET (level unless q is given)."""
        self.client.mav.set_attitude_target_send(0, self.quad.sysid, 1, mask, q or LEVEL_Q,
                                                 0.0, 0.0, 0.0, thrust)

    def vision(self) -> None:
        """One VISION_POSITION_ESTIMATE of the true pose (mocap forwarded), NED."""
        p = self.fleet.p[0]
        self.client.mav.vision_position_estimate_send(
            int(self.clock.now() * 1e6), float(p[0]), float(p[1]), float(p[2]), 0.0, 0.0, 0.0)

    def altitude(self) -> float:
        """Height above ground [m]."""
        return -float(self.fleet.p[0, 2])
