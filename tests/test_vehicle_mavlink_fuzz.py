"""Fuzzing the simulated autopilots' MAVLink input: thousands of random and boundary messages
(NaN, ±inf, 0, huge, negative, random enums and command ids, wrong targets, garbage bytes)
for both flavours, deterministic (fixed seeds) and bounded in time.

The vehicles are driven in-process: each autopilot's UDP link is replaced by a
:class:`MemoryLink` that decodes what the test queued and what the vehicle sends, and the
fleet is ticked on a :class:`~agent.clock.ManualClock`. Checked: every COMMAND_LONG /
COMMAND_INT addressed to a vehicle (by that autopilot's own rule, written out here from the
ArduPilot and PX4 sources independently of the simulator) gets exactly one COMMAND_ACK with
its command id, in order, to its sender; unknown commands are UNSUPPORTED; nothing reached the
fleet's last-line guard (the handlers answered everything themselves); afterwards each
vehicle is put right over MAVLink as a ground station would and still flies (mode, arm,
take-off). A last test does the same over UDP against the running fleet thread.
"""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from agent.clock import ManualClock, WallClock
from agent.flight.frames import quat_from_euler
from agent.wire.mavlink import mavlink, mavutil
from groundstation.vehicle.autopilot import Autopilot
from groundstation.vehicle.fleet import SimFleet
from groundstation.vehicle.params import ARDUPILOT_PARAMS, PX4_PARAMS, VehicleParams

M = mavlink
NAN, INF = math.nan, math.inf
FLT_MAX = struct.unpack("<f", b"\xff\xff\x7f\x7f")[0]
CLIENT = (255, 190)
#: Take-off thrust: ArduCopter's default reads it as a climb rate (0.7: +1 m/s); PX4 as
#: real thrust (hover 0.5).
THRUST = {False: 0.7, True: 0.8}


def _px4(quad: Autopilot) -> bool:
    """The vehicle runs the PX4 flavour."""
    return quad.flavour.name == "px4"


#: Commands the simulator handles, and a few real ones it does not.
HANDLED = [M.MAV_CMD_COMPONENT_ARM_DISARM, M.MAV_CMD_DO_SET_MODE, M.MAV_CMD_NAV_LAND,
           M.MAV_CMD_NAV_RETURN_TO_LAUNCH, M.MAV_CMD_SET_MESSAGE_INTERVAL,
           M.MAV_CMD_GET_MESSAGE_INTERVAL, M.MAV_CMD_REQUEST_MESSAGE,
           M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, M.MAV_CMD_NAV_TAKEOFF,
           M.MAV_CMD_GET_HOME_POSITION, M.MAV_CMD_MISSION_START]
UNHANDLED = [M.MAV_CMD_DO_REPOSITION, M.MAV_CMD_DO_SET_MISSION_CURRENT,
             M.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, M.MAV_CMD_REQUEST_PROTOCOL_VERSION,
             M.MAV_CMD_DO_FLIGHTTERMINATION, 0, 65535]
FLOATS = [NAN, -NAN, INF, -INF, 0.0, -0.0, 1.0, -1.0, 0.5, 0.7, 1.5, 2.0, 4.0, 6.0, 20.0, 29.0,
          21196.0, 2989.0, 1e-45, 1e-38, FLT_MAX, -FLT_MAX, 2.0**31, -(2.0**31), 2.0**32,
          65535.0, 65536.0, 1e6, -1e6, 1e9, 100_000.0]
INT_TYPES = {"uint8_t": (0, 0xFF), "int8_t": (-0x80, 0x7F), "uint16_t": (0, 0xFFFF),
             "int16_t": (-0x8000, 0x7FFF), "uint32_t": (0, 0xFFFFFFFF),
             "int32_t": (-(2**31), 2**31 - 1), "uint64_t": (0, 2**64 - 1),
             "int64_t": (-(2**63), 2**63 - 1)}
PARAM_NAMES = [n.encode() for n in {*ARDUPILOT_PARAMS, *PX4_PARAMS}] + [b"", b"NO_SUCH_PARAM"]
HANDLED_TYPES = ["COMMAND_LONG", "COMMAND_INT", "SET_ATTITUDE_TARGET", "SET_MODE", "PARAM_SET",
                 "PARAM_REQUEST_READ", "PARAM_REQUEST_LIST", "REQUEST_DATA_STREAM",
                 "HEARTBEAT", "VISION_POSITION_ESTIMATE", "ODOMETRY", "ATT_POS_MOCAP"]
OTHER_TYPES = ["SET_POSITION_TARGET_LOCAL_NED", "SET_POSITION_TARGET_GLOBAL_INT",
               "MISSION_REQUEST_LIST", "MISSION_COUNT", "MISSION_ITEM_INT", "MANUAL_CONTROL",
               "COMMAND_ACK", "RC_CHANNELS_OVERRIDE"]
#: Zero bytes that complete and then skip any frame a garbage datagram left half-parsed: the
#: vehicle's parser is a byte stream across datagrams (as ArduPilot's), so garbage could
#: swallow the next good message; a ground station's next packets would do the same.
FLUSH = bytes(300)
RESULTS = {M.MAV_RESULT_ACCEPTED, M.MAV_RESULT_TEMPORARILY_REJECTED, M.MAV_RESULT_DENIED,
           M.MAV_RESULT_UNSUPPORTED, M.MAV_RESULT_FAILED}


class MemoryLink:
    """A vehicle's link without a socket: the test queues encoded datagrams in ``inbox``;
    what the vehicle sends is decoded into ``sent``."""

    port = 0

    def __init__(self, sysid: int) -> None:
        self.mav = M.MAVLink(self, srcSystem=sysid, srcComponent=1)
        self.mav.robust_parsing = True
        self._decoder = M.MAVLink(None)
        self._decoder.robust_parsing = True
        self.inbox: list[bytes] = []
        self.sent: list[Any] = []

    def write(self, buf: bytes) -> None:
        self.sent.extend(self._decoder.parse_buffer(buf) or [])

    def receive(self) -> list[Any]:
        """Every queued datagram, parsed as the UDP link does (bad bytes skipped)."""
        out: list[Any] = []
        for data in self.inbox:
            try:
                out.extend(self.mav.parse_buffer(data) or [])
            except M.MAVError:
                continue
        self.inbox.clear()
        return out

    def take(self, kind: str) -> list[Any]:
        """The sent messages of ``kind`` (removed)."""
        got = [m for m in self.sent if m.get_type() == kind]
        self.sent = [m for m in self.sent if m.get_type() != kind]
        return got

    def close(self) -> None:
        """Nothing to close."""


def addressed(px4: bool, sysid: int, msg: Any) -> bool:
    """Whether the autopilot processes (and must acknowledge) this command: ArduPilot's
    MAVLink_routing (system and component ours or 0), PX4's evaluate_target_ok (system ours,
    component ours or 0; REQUEST_AUTOPILOT_CAPABILITIES / PROTOCOL_VERSION: system ours or 0)."""
    ts, tc = msg.target_system, msg.target_component
    if not px4:
        return ts in (0, sysid) and tc in (0, 1)
    if msg.command in (M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES,
                       M.MAV_CMD_REQUEST_PROTOCOL_VERSION):
        return ts in (0, sysid)
    return ts == sysid and tc in (0, 1)


class Fuzzer:
    """Random and boundary MAVLink messages for vehicle ``sysid`` (seeded)."""

    def __init__(self, seed: int, sysid: int) -> None:
        self.rng = np.random.default_rng(seed)
        self.sysid = sysid
        self.enc = M.MAVLink(None, srcSystem=CLIENT[0], srcComponent=CLIENT[1])

    def pick(self, seq: list[Any]) -> Any:
        return seq[int(self.rng.integers(len(seq)))]

    def real(self) -> float:
        """A boundary float, a random one, or any float32 bit pattern (NaN payloads too)."""
        r = self.rng.random()
        if r < 0.5:
            return float(self.pick(FLOATS))
        if r < 0.75:
            return float(self.rng.uniform(-1e4, 1e4))
        return float(struct.unpack("<f", self.rng.bytes(4))[0])

    def integer(self, ftype: str) -> int:
        lo, hi = INT_TYPES[ftype]
        if self.rng.random() < 0.5:
            return int(self.pick([lo, hi, 0, 1, lo + 1, hi - 1, 2, 6, 20]))
        return int(self.rng.integers(lo, hi, endpoint=True, dtype=np.uint64 if lo == 0 else
                                     np.int64))

    def field(self, name: str, ftype: str, n: int) -> Any:
        if ftype == "char":
            return self.pick(PARAM_NAMES) if self.rng.random() < 0.6 else self.rng.bytes(
                int(self.rng.integers(n + 1)))
        one: Callable[[], Any] = (self.real if ftype in ("float", "double")
                                  else lambda: self.integer(ftype))
        if name == "target_system":
            return self.pick([self.sysid] * 6 + [0, 1, 2, 255])
        if name == "target_component":
            return self.pick([1] * 6 + [0, 190, 255])
        if name == "command":
            return self.pick(HANDLED * 3 + UNHANDLED) if self.rng.random() < 0.9 else one()
        if name == "q" and self.rng.random() < 0.5:
            return [float(a) for a in quat_from_euler(*self.rng.uniform(-1, 1, 3))]
        return [one() for _ in range(n)] if n else one()

    def message(self) -> tuple[Any, list[bytes]]:
        """One message (None for garbage) and its datagrams on the wire."""
        r = self.rng.random()
        if r < 0.03:
            return None, [self.rng.bytes(int(self.rng.integers(1, 300))), FLUSH]
        kind = (self.pick(["COMMAND_LONG", "COMMAND_INT"]) if r < 0.45 else
                self.pick(HANDLED_TYPES) if r < 0.9 else self.pick(OTHER_TYPES))
        cls = M.mavlink_map[getattr(M, f"MAVLINK_MSG_ID_{kind}")]
        lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))  # wire order
        msg = cls(*(self.field(f, t, lengths[f]) for f, t in
                    zip(cls.fieldnames, cls.fieldtypes, strict=True)))
        buf = msg.pack(self.enc)
        if self.rng.random() < 0.02:  # a corrupted copy: checksum or length wrong
            i = int(self.rng.integers(len(buf)))
            return None, [buf[:i] + bytes([buf[i] ^ 0x5A]) + buf[i + 1:], FLUSH]
        return msg, [buf]


def _memory_fleet(autopilot: str, n: int = 2) -> tuple[SimFleet, ManualClock, list[MemoryLink]]:
    clock = ManualClock()
    fleet = SimFleet([f"d{i}" for i in range(n)], clock, VehicleParams(autopilot=autopilot),
                     seed=7)
    links = []
    for q in fleet.quads:
        q.link.close()
        q.link = MemoryLink(q.sysid)
        links.append(q.link)
    return fleet, clock, links


def _tick(fleet: SimFleet, clock: ManualClock, dt: float = 0.01) -> None:
    clock.advance(dt)
    fleet.tick()


class Client:
    """A ground station on one vehicle's memory link (commands wait for their ACK)."""

    def __init__(self, fleet: SimFleet, clock: ManualClock, quad: Autopilot) -> None:
        self.fleet, self.clock, self.quad = fleet, clock, quad
        self.link: MemoryLink = quad.link
        self.enc = M.MAVLink(None, srcSystem=CLIENT[0], srcComponent=CLIENT[1])

    def send(self, msg: Any) -> None:
        self.link.inbox.append(msg.pack(self.enc))

    def command(self, cmd: int, *params: float) -> int:
        p = [*params, NAN, NAN, NAN, NAN, NAN, NAN, NAN][:7]
        self.send(M.MAVLink_command_long_message(self.quad.sysid, 1, cmd, 0, *p))
        _tick(self.fleet, self.clock)
        acks = self.link.take("COMMAND_ACK")
        assert [a.command for a in acks] == [cmd]
        return int(acks[0].result)

    def attitude(self, thrust: float) -> None:
        q = [float(a) for a in quat_from_euler(0.0, 0.0, 0.0)]
        self.send(M.MAVLink_set_attitude_target_message(0, self.quad.sysid, 1, 7, q, 0.0, 0.0,
                                                        0.0, thrust))

    def run(self, sim_s: float, every: Callable[[], None] | None = None) -> None:
        for _ in range(round(sim_s / 0.01)):
            if every is not None:
                every()
            _tick(self.fleet, self.clock)


def _fuzz(fleet: SimFleet, clock: ManualClock, links: list[MemoryLink], count: int,
          seed: int) -> None:
    """``count`` fuzzed messages to each vehicle, 8 per tick; checks the ACKs as it goes."""
    fuzzers = [Fuzzer(seed + q.sysid, q.sysid) for q in fleet.quads]
    expected: list[list[int]] = [[] for _ in fleet.quads]
    unknown: list[set[int]] = [set() for _ in fleet.quads]
    for _ in range(count // 8):
        for q, fz, link in zip(fleet.quads, fuzzers, links, strict=True):
            for _ in range(8):
                msg, datagrams = fz.message()
                link.inbox.extend(datagrams)
                kind = None if msg is None else msg.get_type()
                if kind in ("COMMAND_LONG", "COMMAND_INT") and addressed(_px4(q), q.sysid, msg):
                    expected[q.i].append(msg.command)
                    if msg.command not in HANDLED:
                        unknown[q.i].add(msg.command)
        _tick(fleet, clock)
        for q, link in zip(fleet.quads, links, strict=True):
            acks = link.take("COMMAND_ACK")
            got = [a.command for a in acks]
            want, expected[q.i] = expected[q.i][:len(got)], expected[q.i][len(got):]
            assert got == want, f"{q.name}: ACKs {got}, expected {want}"
            assert all((a.target_system, a.target_component) == CLIENT for a in acks)
            assert all(a.result in RESULTS for a in acks)
            assert all(a.result == M.MAV_RESULT_UNSUPPORTED for a in acks
                       if a.command in unknown[q.i] and a.command not in HANDLED)
            link.sent.clear()
        assert fleet.handler_errors == 0  # every message answered by its handler
    assert expected == [[] for _ in fleet.quads]  # no command left without its ACK


def _take_off(client: Client, thrust: float) -> None:
    """Mode, arm, climb for a second: the storm then hits a flying vehicle too."""
    client.run(0.2, lambda: client.attitude(thrust))  # PX4 OFFBOARD needs fresh set-points
    mode = 6 if _px4(client.quad) else 20  # OFFBOARD / GUIDED_NOGPS
    assert client.command(M.MAV_CMD_DO_SET_MODE, 1, mode) == M.MAV_RESULT_ACCEPTED
    assert client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0) == M.MAV_RESULT_ACCEPTED
    client.run(1.5, lambda: client.attitude(thrust))


def _put_right_and_fly(client: Client, wire: dict[str, tuple[float, int]]) -> None:
    """What a ground station does after the storm: default HEARTBEAT rate, parameters back,
    force-disarm, wait on the ground; then mode, arm and take-off must all work."""
    quad = client.quad
    assert client.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_HEARTBEAT, 0) == 0
    for name, (value, ptype) in wire.items():
        client.send(M.MAVLink_param_set_message(quad.sysid, 1, name.encode(), value, ptype))
    assert client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0.0, 21196.0) == 0
    for _ in range(60):  # falls from wherever the storm flew it
        client.run(1.0)
        if client.fleet.on_ground(quad.i):
            break
    assert client.fleet.on_ground(quad.i) and not quad.armed
    client.link.sent.clear()
    _take_off(client, THRUST[_px4(quad)])
    assert -client.fleet.p[quad.i, 2] > 0.5, "the vehicle did not take off"
    client.run(1.5, lambda: client.attitude(THRUST[_px4(quad)]))
    assert len(client.link.take("HEARTBEAT")) >= 3  # 3.2 s of flight: heard from at 1 Hz


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_fuzzed_mavlink_is_answered_and_the_vehicles_still_fly(autopilot: str) -> None:
    fleet, clock, links = _memory_fleet(autopilot)
    with fleet:
        wire = {n: fleet.quads[0].params_table.to_wire(n) for n in fleet.quads[0].params_table}
        for q in fleet.quads:
            _take_off(Client(fleet, clock, q), THRUST[_px4(q)])
        assert all(q.armed and not q.landed for q in fleet.quads)
        t0 = time.monotonic()
        _fuzz(fleet, clock, links, count=4000, seed=20261124)
        fuzz_s = time.monotonic() - t0
        for q in fleet.quads:
            per_vehicle = dict(wire)
            per_vehicle.pop("MAV_SYS_ID" if _px4(q) else "SYSID_THISMAV")
            _put_right_and_fly(Client(fleet, clock, q), per_vehicle)
        assert fleet.handler_errors == 0
    assert fuzz_s < 20.0  # bounded (a few seconds on a loaded 2-core machine)


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_fuzzed_mavlink_over_udp_does_not_stop_the_fleet_thread(autopilot: str) -> None:
    """The same storm over loopback UDP against the running fleet thread (the ground
    station's set-up): the thread lives, the guard caught nothing, an arm is still ACKed."""
    fleet = SimFleet(["A"], WallClock(), VehicleParams(autopilot=autopilot)).start()
    gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{fleet.quads[0].port}",
                                     source_system=CLIENT[0], source_component=CLIENT[1])
    try:
        fz = Fuzzer(99, 1)
        for i in range(1500):
            for datagram in fz.message()[1]:
                gcs.write(datagram)
            if i % 25 == 24:
                time.sleep(0.01)  # let the loop drain the socket
        gcs.write(FLUSH)  # in case a flush datagram was dropped on a loaded machine
        time.sleep(0.2)
        assert fleet._thread is not None and fleet._thread.is_alive()
        assert fleet.handler_errors == 0
        while gcs.recv_match(blocking=False) is not None:
            pass
        gcs.mav.command_long_send(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0.0, 21196.0,
                                  NAN, NAN, NAN, NAN, NAN)
        ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=2.0)
        assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    finally:
        gcs.close()
        fleet.close()
