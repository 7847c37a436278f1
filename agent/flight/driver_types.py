"""What the MAVLink driver is configured with, receives and reports: settings, the pose
samples it flies on, its counters, the vehicle's last reported state, and the connection
string rules. Plain data, no I/O."""

from __future__ import annotations

import struct
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from agent.flight.flavours import flavour
from agent.wire.mavlink import mavlink

Array = NDArray[np.float64]


class FlightError(RuntimeError):
    """A handshake step failed (no vehicle, command refused, timeout); the message says which."""


@dataclass
class PoseSample:
    """A pose for the controller: capture time t [s sim], position p [m; world ENU], velocity
    vel [m/s; world ENU], attitude q (w, x, y, z) R_ENU←FLU, and the wall time it reached this
    process (for latency)."""

    t: float
    p: Array
    vel: Array
    q: Array
    rx_wall: float = 0.0


PoseProvider = Callable[[], PoseSample | None]


@dataclass
class DriverConfig:
    """Driver settings. Rates in Hz and durations in s of simulation time. ``autopilot`` is
    a flavour's name (:mod:`agent.flight.flavours`); ``forward`` must be "none" when the
    pose comes from the autopilot itself."""

    autopilot: str = "ardupilot"
    rate_hz: float = 50.0
    slack: float = 0.15
    forward: str = "vision"  # "vision" | "odometry" | "none"
    forward_hz: float = 50.0
    mocap_stale_s: float = 0.2
    failsafe_hold_s: float = 1.0
    yaw_rate_ff: bool = False
    set_guid_options: bool = True
    prestream_s: float = 1.0  #: set-points before a stream-gated mode (PX4 OFFBOARD) [s]
    ack_timeout_s: float = 1.5
    heartbeat_timeout_s: float = 3.0  #: no HEARTBEAT this long: link lost (also at connect)
    battery_critical_pct: float = 15.0  #: battery remaining at or below this: leave [%]
    retries: int = 3
    target_system: int = 0  # 0: the first vehicle that sends a HEARTBEAT
    target_component: int = 1
    source_component: int = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER

    def __post_init__(self) -> None:
        flavour(self.autopilot)  # ValueError (one line) for an unknown autopilot
        if self.forward not in ("vision", "odometry", "none"):
            raise ValueError(f"forward must be vision, odometry or none, got {self.forward!r}")
        if not self.rate_hz > 0:
            raise ValueError("rate_hz must be > 0")


@dataclass
class DriverStats:
    """Counters and wall-clock timings (s) of the set-point stream."""

    sent: int = 0
    blocked: int = 0
    dropped: int = 0
    forwarded: int = 0
    failsafes: int = 0
    clamped: int = 0  #: position targets clamped into the space
    send_wall: deque[float] = field(default_factory=lambda: deque(maxlen=20000))
    latency: deque[float] = field(default_factory=lambda: deque(maxlen=20000))


@dataclass
class VehicleState:
    """What the vehicle last told us (HEARTBEAT, ATTITUDE, LOCAL_POSITION_NED)."""

    heartbeat_wall: float = 0.0
    armed: bool = False
    custom_mode: int = -1
    autopilot: int = -1
    attitude: tuple[float, float, float] | None = None
    position_ned: tuple[float, float, float, float, float, float] | None = None
    params: dict[str, float] = field(default_factory=dict)
    param_types: dict[str, int] = field(default_factory=dict)


#: struct formats of the MAVLink integer parameter types (MAV_PARAM_TYPE) in the first bytes
#: of PARAM_VALUE.param_value when the autopilot encodes byte-wise (PX4).
_BYTEWISE = {mavlink.MAV_PARAM_TYPE_UINT8: "<B", mavlink.MAV_PARAM_TYPE_INT8: "<b",
             mavlink.MAV_PARAM_TYPE_UINT16: "<H", mavlink.MAV_PARAM_TYPE_INT16: "<h",
             mavlink.MAV_PARAM_TYPE_UINT32: "<I", mavlink.MAV_PARAM_TYPE_INT32: "<i"}


def decode_param_value(value: float, param_type: int, bytewise: bool) -> float:
    """The parameter's value from PARAM_VALUE (param_value, param_type). ArduPilot casts every
    value to a float (``bytewise`` False: returned as is); PX4 copies an integer's bytes into
    the float field (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE: INT32 3 arrives as the
    float 4.2e-45), so with ``bytewise`` integers are re-read from the float's four bytes."""
    fmt = _BYTEWISE.get(param_type)
    if not bytewise or fmt is None:
        return float(value)
    raw = struct.pack("<f", value)
    return float(struct.unpack(fmt, raw[:struct.calcsize(fmt)])[0])


def split_baud(connection: str, default: int = 115200) -> tuple[str, int]:
    """``/dev/ttyAMA0,921600`` → (device, baud) for serial links; network strings unchanged."""
    if "," in connection and not connection.startswith(("udp", "tcp", "uds")):
        device, _, baud = connection.rpartition(",")
        if not baud.isdigit() or int(baud) <= 0:
            raise FlightError(f"bad baud rate in MAVLink connection {connection!r}; "
                              "use DEVICE,BAUD, e.g. /dev/ttyAMA0,921600")
        return device, int(baud)
    return connection, default
