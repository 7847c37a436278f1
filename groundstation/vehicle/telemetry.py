"""What a simulated autopilot sends without being asked, and at which intervals.

Message intervals [s] per MAVLink message id, changed by MAV_CMD_SET_MESSAGE_INTERVAL
(interval in µs; −1 stops it, 0 restores the default) and, ArduPilot only, by the legacy
REQUEST_DATA_STREAM (stream groups as ArduCopter/GCS_Mavlink.cpp defines them:
EXTENDED_STATUS = SYS_STATUS..., POSITION = GLOBAL_POSITION_INT + LOCAL_POSITION_NED,
EXTRA1 = ATTITUDE..., EXTRA3 = BATTERY_STATUS...). HEARTBEAT is always 1 Hz.

Defaults: HEARTBEAT 1 Hz, SYS_STATUS 1 Hz, EXTENDED_SYS_STATE 1 Hz, BATTERY_STATUS 1 Hz,
ATTITUDE and LOCAL_POSITION_NED at the vehicle's ``telemetry_rate``. ArduPilot streams
GLOBAL_POSITION_INT with LOCAL_POSITION_NED (its POSITION group) and sends
ATTITUDE_QUATERNION (in no stream group) only when asked; PX4's "normal" MAVLink mode
(mavlink_main.cpp ``configure_streams_to_default``) streams GLOBAL_POSITION_INT at 5 Hz,
ATTITUDE_QUATERNION at 10 Hz and HOME_POSITION at 0.5 Hz. ArduPilot sends HOME_POSITION when
home is set and on request. AUTOPILOT_VERSION only on request (MAV_CMD_REQUEST_MESSAGE or
MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES). Positions and units:
:mod:`groundstation.vehicle.conventions`.

Encoders (:func:`encode`) take the vehicle's view (:class:`VehicleView`); every time field is
simulation time.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

from agent.flight.frames import quat_from_euler
from agent.wire.mavlink import mavlink as mav
from groundstation.vehicle.conventions import body_rates, geodetic, heading_cdeg

if TYPE_CHECKING:
    from groundstation.vehicle.flavours.base import SimFlavour

Array = NDArray[np.float64]

HEARTBEAT = mav.MAVLINK_MSG_ID_HEARTBEAT
SYS_STATUS = mav.MAVLINK_MSG_ID_SYS_STATUS
ATTITUDE = mav.MAVLINK_MSG_ID_ATTITUDE
LOCAL_POSITION_NED = mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED
HOME_POSITION = mav.MAVLINK_MSG_ID_HOME_POSITION
EXTENDED_SYS_STATE = mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE
BATTERY_STATUS = mav.MAVLINK_MSG_ID_BATTERY_STATUS
AUTOPILOT_VERSION = mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION
GLOBAL_POSITION_INT = mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
ATTITUDE_QUATERNION = mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION

#: Legacy REQUEST_DATA_STREAM groups (ArduPilot) → the messages we simulate of each.
DATA_STREAMS: dict[int, tuple[int, ...]] = {
    mav.MAV_DATA_STREAM_EXTENDED_STATUS: (SYS_STATUS, EXTENDED_SYS_STATE,
                                          mav.MAVLINK_MSG_ID_MISSION_CURRENT),
    mav.MAV_DATA_STREAM_POSITION: (GLOBAL_POSITION_INT, LOCAL_POSITION_NED),
    mav.MAV_DATA_STREAM_EXTRA1: (ATTITUDE,),
    mav.MAV_DATA_STREAM_EXTRA3: (BATTERY_STATUS,),
}


class VehicleView(Protocol):
    """What the encoders read from an autopilot."""

    sysid: int
    flavour: SimFlavour  #: the autopilot's simulated flavour (its streams, ids, version)
    origin: tuple[float, float, float]  #: EKF origin: lat, lon [deg], alt [m AMSL]

    @property
    def mav(self) -> mav.MAVLink:
        """The encoder that sends on the vehicle's link."""
        ...

    def heartbeat_fields(self) -> tuple[int, int, int]:
        """(base_mode, custom_mode, system_status)."""
        ...

    def landed_state(self) -> int:
        """MAV_LANDED_STATE."""
        ...

    def estimate(self) -> tuple[Array, Array, Array, Array]:
        """The EKF's view: p [m; NED], v [m/s; NED], attitude (roll, pitch, yaw) [rad],
        Euler rates [rad/s]."""
        ...

    def home_ned(self) -> Array:
        """Home position [m; NED]."""
        ...

    def battery_reading(self) -> Any:
        """The battery monitor's :class:`groundstation.vehicle.battery.Reading`."""
        ...

    def sensor_bits(self, t: float, base: int) -> tuple[int, int, int]:
        """SYS_STATUS (present, enabled, health) given the simulated sensors ``base``."""
        ...


@dataclass
class MessageStreams:
    """Intervals [s sim] of the messages sent unasked, and when each is next due."""

    defaults: dict[int, float]

    def __post_init__(self) -> None:
        self.intervals: dict[int, float] = dict(self.defaults)
        self.next_due: dict[int, float] = dict.fromkeys(self.intervals, 0.0)

    @classmethod
    def for_flavour(cls, flavour: SimFlavour, telemetry_rate: float) -> MessageStreams:
        """The common streams, then ``flavour``'s own (module docstring)."""
        d = {HEARTBEAT: 1.0, SYS_STATUS: 1.0, EXTENDED_SYS_STATE: 1.0, BATTERY_STATUS: 1.0,
             ATTITUDE: 1.0 / telemetry_rate, LOCAL_POSITION_NED: 1.0 / telemetry_rate}
        d.update(flavour.streams(telemetry_rate))
        d.update(DEVICE_STREAMS)  # sent only where the equipment exists (AVAILABLE)
        return cls(d)

    def set_interval(self, msgid: int, interval_us: float, now: float) -> bool:
        """MAV_CMD_SET_MESSAGE_INTERVAL: False if ``msgid`` is not one we can send."""
        if msgid not in ENCODERS or msgid == AUTOPILOT_VERSION:
            return False
        if interval_us < 0:
            self.intervals.pop(msgid, None)
        elif interval_us == 0:
            if msgid in self.defaults:
                self.intervals[msgid] = self.defaults[msgid]
            else:
                self.intervals.pop(msgid, None)
        else:
            self.intervals[msgid] = interval_us * 1e-6
        self.next_due[msgid] = now
        return True

    def interval_us(self, msgid: int) -> int:
        """MESSAGE_INTERVAL.interval_us: −1 when not streamed."""
        iv = self.intervals.get(msgid)
        return -1 if iv is None else round(iv * 1e6)

    def request_data_stream(self, stream_id: int, rate_hz: float, start: bool,
                            now: float) -> None:
        """ArduPilot's legacy REQUEST_DATA_STREAM: set every message of the group (or all
        groups for MAV_DATA_STREAM_ALL) to ``rate_hz`` (0 or ``start`` false: stop)."""
        groups = DATA_STREAMS.values() if stream_id == mav.MAV_DATA_STREAM_ALL else \
            [DATA_STREAMS.get(stream_id, ())]
        for group in groups:
            for msgid in group:
                us = 1e6 / rate_hz if start and rate_hz > 0 else -1.0
                self.set_interval(msgid, us, now)

    def due(self, now: float) -> list[int]:
        """Message ids due at ``now``; their next due times move on by one interval."""
        out = []
        for msgid, iv in self.intervals.items():
            nxt = self.next_due.get(msgid, 0.0)
            if now >= nxt:
                out.append(msgid)
                self.next_due[msgid] = max(nxt + iv, now) if now - nxt < iv else now + iv
        return out


def _ms(t: float) -> int:
    return int(max(t, 0.0) * 1000) & 0xFFFFFFFF


def _heartbeat(v: VehicleView, t: float) -> None:
    base, custom, status = v.heartbeat_fields()
    v.mav.heartbeat_send(mav.MAV_TYPE_QUADROTOR, v.flavour.autopilot.mav_autopilot, base,
                         custom, status)


def _attitude(v: VehicleView, t: float) -> None:
    _, _, att, rates = v.estimate()
    v.mav.attitude_send(_ms(t), *(float(a) for a in att), *(float(a) for a in rates))


def _local_position(v: VehicleView, t: float) -> None:
    p, vel, _, _ = v.estimate()
    v.mav.local_position_ned_send(_ms(t), *(float(a) for a in p), *(float(a) for a in vel))


def _sys_status(v: VehicleView, t: float) -> None:
    """Battery fields: mV, cA, % (−1 unknown) from the battery monitor."""
    r = v.battery_reading()
    sensors = (mav.MAV_SYS_STATUS_SENSOR_3D_GYRO | mav.MAV_SYS_STATUS_SENSOR_3D_ACCEL
               | mav.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
               | mav.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
               | mav.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
               | mav.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | mav.MAV_SYS_STATUS_SENSOR_BATTERY)
    present, enabled, health = v.sensor_bits(t, sensors)
    v.mav.sys_status_send(present, enabled, health, 100, int(r.voltage * 1000),
                          int(r.current * 100), _percent(r.remaining), 0, 0, 0, 0, 0, 0)


def _percent(remaining: float | None) -> int:
    return -1 if remaining is None else math.ceil(remaining * 100.0 - 1e-9)


def _battery_status(v: VehicleView, t: float) -> None:
    """Total voltage in the first cell (as ArduPilot sends an unknown cell count), cA, mAh,
    %, charge_state of the failsafe level reached (:mod:`groundstation.vehicle.battery`)."""
    r = v.battery_reading()
    cells = [65535] * 10
    cells[0] = min(int(r.voltage * 1000), 65534)
    v.mav.battery_status_send(0, mav.MAV_BATTERY_FUNCTION_ALL, mav.MAV_BATTERY_TYPE_LIPO,
                              32767, cells, int(r.current * 100), int(r.consumed), -1,
                              _percent(r.remaining), 0, r.charge_state)


def _extended_sys_state(v: VehicleView, t: float) -> None:
    v.mav.extended_sys_state_send(mav.MAV_VTOL_STATE_UNDEFINED, v.landed_state())


def _home_position(v: VehicleView, t: float) -> None:
    """Home: geodetic and local NED [m] from the EKF origin; q identity (ArduPilot's)."""
    h = v.home_ned()
    lat, lon, alt = geodetic(v.origin, h)
    q = [float(a) for a in quat_from_euler(0.0, 0.0, 0.0)]
    v.mav.home_position_send(lat, lon, alt, float(h[0]), float(h[1]), float(h[2]), q,
                             0.0, 0.0, 0.0, int(max(t, 0.0) * 1e6))


def _global_position_int(v: VehicleView, t: float) -> None:
    """Position from the EKF origin (degE7, mm AMSL), mm above home, cm/s NED, cdeg."""
    p, vel, att, _ = v.estimate()
    lat, lon, alt = geodetic(v.origin, p)
    rel = round((float(v.home_ned()[2]) - float(p[2])) * 1000.0)
    cms = [round(float(a) * 100.0) for a in vel]
    v.mav.global_position_int_send(_ms(t), lat, lon, alt, rel, *cms, heading_cdeg(float(att[2])))


def _attitude_quaternion(v: VehicleView, t: float) -> None:
    """q (w, x, y, z) NED → FRD, body rates [rad/s], no representation offset."""
    _, _, att, rates = v.estimate()
    q = quat_from_euler(float(att[0]), float(att[1]), float(att[2]))
    v.mav.attitude_quaternion_send(_ms(t), *(float(a) for a in q), *body_rates(att, rates),
                                   [0.0, 0.0, 0.0, 0.0])


def _autopilot_version(v: VehicleView, t: float) -> None:
    caps = (mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | mav.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | mav.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
            | mav.MAV_PROTOCOL_CAPABILITY_MISSION_INT | mav.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
            | mav.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY)  # both store fences and rally points
    caps |= v.flavour.version_capabilities
    v.mav.autopilot_version_send(caps, v.flavour.sw_version, 0, 0, 0, [0] * 8, [0] * 8,
                                 [0] * 8, 0, 0, 0x5649530000 + v.sysid)  # "VIS" + sysid: UID


ENCODERS: dict[int, Callable[[Any, float], None]] = {
    HEARTBEAT: _heartbeat, SYS_STATUS: _sys_status, ATTITUDE: _attitude,
    LOCAL_POSITION_NED: _local_position, HOME_POSITION: _home_position,
    EXTENDED_SYS_STATE: _extended_sys_state, BATTERY_STATUS: _battery_status,
    AUTOPILOT_VERSION: _autopilot_version, GLOBAL_POSITION_INT: _global_position_int,
    ATTITUDE_QUATERNION: _attitude_quaternion,
}


#: Whether a vehicle has what a registered message reports (absent: always).
AVAILABLE: dict[int, Callable[[Any], bool]] = {}
#: Default intervals [s] of the registered streams (sent only where available).
DEVICE_STREAMS: dict[int, float] = {}


def register(msgid: int, encoder: Callable[[Any, float], None],
             available: Callable[[Any], bool] | None = None,
             interval: float | None = None) -> None:
    """Add an encoder (of :mod:`groundstation.vehicle.devices`), when the vehicle has it and,
    with ``interval`` [s], a default stream."""
    ENCODERS[msgid] = encoder
    if available is not None:
        AVAILABLE[msgid] = available
    if interval is not None:
        DEVICE_STREAMS[msgid] = interval


def available(view: Any, msgid: int) -> bool:
    """This vehicle produces message ``msgid`` (an encoder, and the equipment behind it)."""
    if msgid not in ENCODERS:
        return False
    check = AVAILABLE.get(msgid)
    return check is None or bool(check(view))


def encode(view: VehicleView, msgid: int, t: float) -> bool:
    """Send message ``msgid`` now; False if this vehicle does not produce it."""
    if not available(view, msgid):
        return False
    ENCODERS[msgid](view, t)
    return True
