"""Simulated vehicle settings and the simulated autopilot's parameter table.

:class:`VehicleParams` extends the validated ``[flight.vehicle]`` section
(:class:`agent.config.flight.VehicleSection`), so its defaults live in one place.

The parameter tables hold the real names, types and defaults of the parameters this
simulator's behaviour depends on (sources, as read with the ``search`` tool):

* ArduCopter: GUID_OPTIONS (AP_Int32, 0) and GUID_TIMEOUT (AP_Float, 3 s) in
  ArduCopter/Parameters.cpp (``get_timeout_ms`` in ArduCopter/mode_guided.cpp clamps it to at
  least 0.1 s); MOT_THST_HOVER (AP_Float, 0.35) and MOT_HOVER_LEARN (AP_Int8, 2) in
  libraries/AP_Motors/AP_MotorsMulticopter.cpp; VISO_TYPE (AP_Int8, 0) in
  libraries/AP_VisualOdom/AP_VisualOdom.cpp; EK3_SRC1_POSXY / VELXY / POSZ / VELZ / YAW
  (AP_Int8; 3 GPS, 3 GPS, 1 baro, 3 GPS, 1 compass) in libraries/AP_NavEKF/AP_NavEKF_Source.cpp;
  WPNAV_SPEED_UP / WPNAV_SPEED_DN (AP_Float, 250 / 150 cm/s) in
  libraries/AC_WPNav/AC_WPNav.cpp; LAND_SPEED (AP_Int16, 50 cm/s); DISARM_DELAY (AP_Int8,
  10 s); RTL_ALT (AP_Int32, 1500 cm).
  ArduPilot sends every value as a float with MAV_PARAM_TYPE of its own type
  (libraries/GCS_MAVLink/GCS_Param.cpp) and casts a PARAM_SET value to that type.
* PX4: MPC_THR_HOVER (float, 0.5), COM_OF_LOSS_T (float, 1.0 s) and COM_OBL_RC_ACT
  (int32, 0 = Position mode) in src/modules/commander/commander_params.c, EKF2_EV_CTRL
  (int32 bitmask, 15) and EKF2_HGT_REF (int32, 1 = GPS) in src/modules/ekf2/params_*.yaml,
  MPC_LAND_SPEED (0.7 m/s), COM_DISARM_LAND (2 s), RTL_RETURN_ALT (60 m). PX4 encodes int32
  values byte-wise in the float field of PARAM_VALUE and takes PARAM_SET's four bytes as the
  parameter's own type (src/modules/mavlink/mavlink_parameters.cpp;
  MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE).

The simulated physics set the hover-thrust parameters (the vehicle's true hover thrust), the
landing speed and ArduCopter's WPNAV_SPEED_UP (``pilot_speed``), and
``setpoint_timeout`` sets GUID_TIMEOUT / COM_OF_LOSS_T unless it is None; ``indoor`` applies
the configuration the README's "Flying real drones" asks for (:data:`INDOOR`: external
navigation from the forwarded mocap, PX4's offboard-loss action Land); ``params`` then
overrides any of them, so a test can set up a wrongly configured autopilot. The ground
station's vehicles (:meth:`VehicleParams.from_section`) are configured indoors; a bare
``VehicleParams()`` is a freshly flashed autopilot (the firmware defaults).

What clients read (QGroundControl, MAVSDK, MAVProxy): ArduCopter FRAME_CLASS / FRAME_TYPE
(AP_Int8 in libraries/AP_Motors; the firmware default is 0 "undefined", ArduPilot SITL's copter
defaults set 1 Quad / 1 X, which this quadrotor is), FENCE_ENABLE (AP_Int8, 0), FENCE_TYPE
(AP_Int8, 7 = max altitude | circle | polygon for Copter) and FENCE_ACTION (AP_Int8, 1) in
libraries/AC_Fence/AC_Fence.cpp; PX4 SYS_AUTOSTART (int32; 4001 = the SITL x500 quadrotor
airframe, 0 on a bare board), MAV_TYPE (int32, 2 quadrotor, set by that airframe) and
MIS_TAKEOFF_ALT (float, 2.5 m, src/modules/navigator/mission_params.c).

Outdoor equipment (camera, gimbal, fence, battery failsafe, GNSS source) and their
parameters, each with the source it was read from: :mod:`groundstation.vehicle.camera`,
:mod:`.gimbal`, :mod:`.fence`, :mod:`.battery`, :mod:`.ekf` (MNT1_* limits are AP_Int16
degrees; the battery monitor type BATT_MONITOR is 4, analog voltage and current, as ArduPilot
SITL sets it; BATT_CAPACITY / BAT1_N_CELLS are set from the simulated pack).

Missions in AUTO (:mod:`groundstation.vehicle.mission_exec`): ArduCopter MIS_RESTART (AP_Int8,
0 resume) in libraries/AP_Mission/AP_Mission.cpp, AUTO_OPTIONS (AP_Int32, 0; bit 0 allow
arming, bit 1 take off without raising the throttle) in ArduCopter/Parameters.cpp,
WPNAV_SPEED (1000 cm/s), WPNAV_RADIUS (200 cm), WPNAV_ACCEL (250 cm/s²) in
libraries/AC_WPNav/AC_WPNav.cpp, WP_YAW_BEHAVIOR (AP_Int8, 2: face the next waypoint); PX4
MPC_XY_CRUISE (5 m/s), MPC_ACC_HOR (3 m/s²), MPC_Z_V_AUTO_UP / _DN (3 / 1.5 m/s),
MPC_TKO_SPEED (1.5 m/s) in src/modules/mc_pos_control, NAV_ACC_RAD (10 m in
src/modules/navigator/navigator_params.c, 2 m as the multicopter airframes' rc.mc_defaults
set it), NAV_MC_ALT_RAD (0.8 m), MIS_YAW_ERR (12°) in mission_params.c.

Also: AHRS_EKF_TYPE (AP_Int8, 3 = EKF3) in libraries/AP_AHRS/AP_AHRS.cpp and ARMING_CHECK
(AP_Int32 bitmask, 1 = all) in libraries/AP_Arming/AP_Arming.cpp, read by the pre-flight
check only.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator, MutableMapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import msgspec

from agent.config.flight import VehicleSection
from agent.wire.mavlink import flavour
from agent.wire.mavlink import mavlink as mav

if TYPE_CHECKING:
    from groundstation.vehicle.flavours.base import SimFlavour

INT8, INT16, INT32, REAL32 = (mav.MAV_PARAM_TYPE_INT8, mav.MAV_PARAM_TYPE_INT16,
                              mav.MAV_PARAM_TYPE_INT32, mav.MAV_PARAM_TYPE_REAL32)


class VehicleParams(VehicleSection, kw_only=True):
    """One simulated vehicle: the ``[flight.vehicle]`` settings plus the autopilot flavour
    (a registered flavour's name: ``ardupilot``, ``px4``) and gravity g [m/s²]."""

    autopilot: str = "ardupilot"
    g: float = 9.81
    indoor: bool = False  #: configured for mocap flight (:data:`INDOOR`)
    #: EKF origin (latitude, longitude [deg], altitude [m AMSL]) of the local NED frame;
    #: None: this flavour's SITL default (:data:`groundstation.vehicle.conventions.ORIGIN`).
    origin: tuple[float, float, float] | None = None
    #: GNSS receiver: "rtk", "3d" or None (none); its error model and ``gnss_noise``
    #: overrides (field → value): :mod:`groundstation.vehicle.ekf`.
    gnss: str | None = None
    gnss_noise: dict[str, float] = msgspec.field(default_factory=dict)
    #: The airframe carries the inspection camera and a pitch/yaw gimbal, set up as
    #: :data:`PAYLOAD` says (:mod:`groundstation.vehicle.camera`, :mod:`.gimbal`).
    payload: bool = False
    #: The gimbal's slew rate [deg/s] per axis (physics; no MAVLink message carries it).
    gimbal_rate: float = 60.0

    def __post_init__(self) -> None:
        super().__post_init__()
        flavour(self.autopilot)  # ValueError (one line, naming the known ones) otherwise
        if self.gnss not in (None, "rtk", "3d"):
            raise ValueError(f"gnss must be 'rtk', '3d' or omitted, got {self.gnss!r}")
        if not self.gimbal_rate > 0:
            raise ValueError("gimbal_rate must be > 0 [deg/s]")

    @classmethod
    def from_section(cls, section: VehicleSection, autopilot: str, indoor: bool = True,
                     gnss: str | None = None, payload: bool = True) -> VehicleParams:
        """The vehicle of a validated ``[flight.vehicle]`` section, configured for indoor
        flight on mocap unless ``indoor`` is False, with a GNSS receiver ``gnss`` and the
        camera / gimbal payload (``params`` still override)."""
        fields = {f: getattr(section, f) for f in section.__struct_fields__}
        return cls(autopilot=autopilot, indoor=indoor, gnss=gnss, payload=payload, **fields)

    @property
    def max_thrust(self) -> float:
        """T_max [N] = m g / hover_thrust."""
        return self.mass * self.g / self.hover_thrust


@dataclass(frozen=True)
class ParamSpec:
    """A parameter: its MAV_PARAM_TYPE and its default (in the parameter's own units)."""

    type: int
    default: float


ARDUPILOT_PARAMS: dict[str, ParamSpec] = {
    "SYSID_THISMAV": ParamSpec(INT16, 1),
    "AHRS_EKF_TYPE": ParamSpec(INT8, 3),
    "ARMING_CHECK": ParamSpec(INT32, 1),
    "GUID_OPTIONS": ParamSpec(INT32, 0),
    "GUID_TIMEOUT": ParamSpec(REAL32, 3.0),
    "MOT_THST_HOVER": ParamSpec(REAL32, 0.35),
    "MOT_HOVER_LEARN": ParamSpec(INT8, 2),
    "VISO_TYPE": ParamSpec(INT8, 0),
    "EK3_SRC1_POSXY": ParamSpec(INT8, 3),
    "EK3_SRC1_VELXY": ParamSpec(INT8, 3),
    "EK3_SRC1_POSZ": ParamSpec(INT8, 1),
    "EK3_SRC1_VELZ": ParamSpec(INT8, 3),
    "EK3_SRC1_YAW": ParamSpec(INT8, 1),
    "WPNAV_SPEED_UP": ParamSpec(REAL32, 250.0),
    "WPNAV_SPEED_DN": ParamSpec(REAL32, 150.0),
    "LAND_SPEED": ParamSpec(INT16, 50),
    "DISARM_DELAY": ParamSpec(INT8, 10),
    "RTL_ALT": ParamSpec(INT32, 1500),
    "BATT_CAPACITY": ParamSpec(INT32, 3300),
    "FS_GCS_ENABLE": ParamSpec(INT8, 0),
    "FRAME_CLASS": ParamSpec(INT8, 1),
    "FRAME_TYPE": ParamSpec(INT8, 1),
    "FENCE_ENABLE": ParamSpec(INT8, 0),
    "FENCE_TYPE": ParamSpec(INT8, 7),
    "FENCE_ACTION": ParamSpec(INT8, 1),
    "FENCE_ALT_MAX": ParamSpec(REAL32, 100.0),
    "FENCE_ALT_MIN": ParamSpec(REAL32, -10.0),
    "FENCE_RADIUS": ParamSpec(REAL32, 300.0),
    "FENCE_MARGIN": ParamSpec(REAL32, 2.0),
    "BATT_MONITOR": ParamSpec(INT8, 4),
    "BATT_LOW_VOLT": ParamSpec(REAL32, 10.5),
    "BATT_CRT_VOLT": ParamSpec(REAL32, 0.0),
    "BATT_LOW_MAH": ParamSpec(REAL32, 0.0),
    "BATT_CRT_MAH": ParamSpec(REAL32, 0.0),
    "BATT_FS_LOW_ACT": ParamSpec(INT8, 0),
    "BATT_FS_CRT_ACT": ParamSpec(INT8, 0),
    "BATT_LOW_TIMER": ParamSpec(INT8, 10),
    "CAM1_TYPE": ParamSpec(INT8, 0),
    "CAM1_INTRVAL_MIN": ParamSpec(REAL32, 0.0),
    "MNT1_TYPE": ParamSpec(INT8, 0),
    "MNT1_ROLL_MIN": ParamSpec(INT16, -30),
    "MNT1_ROLL_MAX": ParamSpec(INT16, 30),
    "MNT1_PITCH_MIN": ParamSpec(INT16, -90),
    "MNT1_PITCH_MAX": ParamSpec(INT16, 20),
    "MNT1_YAW_MIN": ParamSpec(INT16, -180),
    "MNT1_YAW_MAX": ParamSpec(INT16, 180),
    "MIS_RESTART": ParamSpec(INT8, 0),
    "AUTO_OPTIONS": ParamSpec(INT32, 0),
    "WPNAV_SPEED": ParamSpec(REAL32, 1000.0),
    "WPNAV_RADIUS": ParamSpec(REAL32, 200.0),
    "WPNAV_ACCEL": ParamSpec(REAL32, 250.0),
    "WP_YAW_BEHAVIOR": ParamSpec(INT8, 2),
}

PX4_PARAMS: dict[str, ParamSpec] = {
    "MAV_SYS_ID": ParamSpec(INT32, 1),
    "MPC_THR_HOVER": ParamSpec(REAL32, 0.5),
    "MPC_USE_HTE": ParamSpec(INT32, 1),
    "MPC_LAND_SPEED": ParamSpec(REAL32, 0.7),
    "COM_OF_LOSS_T": ParamSpec(REAL32, 1.0),
    "COM_OBL_RC_ACT": ParamSpec(INT32, 0),
    "COM_DISARM_LAND": ParamSpec(REAL32, 2.0),
    "RTL_RETURN_ALT": ParamSpec(REAL32, 60.0),
    "COM_RC_IN_MODE": ParamSpec(INT32, 3),
    "EKF2_EV_CTRL": ParamSpec(INT32, 15),
    "EKF2_HGT_REF": ParamSpec(INT32, 1),
    "EKF2_EV_DELAY": ParamSpec(REAL32, 0.0),
    "BAT1_CAPACITY": ParamSpec(REAL32, -1.0),
    "SYS_AUTOSTART": ParamSpec(INT32, 4001),
    "MAV_TYPE": ParamSpec(INT32, 2),
    "MIS_TAKEOFF_ALT": ParamSpec(REAL32, 2.5),
    "EKF2_GPS_CTRL": ParamSpec(INT32, 7),
    "GF_ACTION": ParamSpec(INT32, 2),
    "GF_MAX_HOR_DIST": ParamSpec(REAL32, 0.0),
    "GF_MAX_VER_DIST": ParamSpec(REAL32, 0.0),
    "COM_FAIL_ACT_T": ParamSpec(REAL32, 5.0),
    "COM_LOW_BAT_ACT": ParamSpec(INT32, 0),
    "BAT_LOW_THR": ParamSpec(REAL32, 0.15),
    "BAT_CRIT_THR": ParamSpec(REAL32, 0.07),
    "BAT_EMERGEN_THR": ParamSpec(REAL32, 0.05),
    "BAT1_V_EMPTY": ParamSpec(REAL32, 3.6),
    "BAT1_V_CHARGED": ParamSpec(REAL32, 4.05),
    "BAT1_N_CELLS": ParamSpec(INT32, 0),
    "MNT_MODE_IN": ParamSpec(INT32, -1),
    "MNT_MODE_OUT": ParamSpec(INT32, 0),
    "MNT_RANGE_ROLL": ParamSpec(REAL32, 90.0),
    "MNT_RANGE_PITCH": ParamSpec(REAL32, 90.0),
    "MNT_RANGE_YAW": ParamSpec(REAL32, 360.0),
    "MNT_OFF_ROLL": ParamSpec(REAL32, 0.0),
    "MNT_OFF_PITCH": ParamSpec(REAL32, 0.0),
    "MNT_OFF_YAW": ParamSpec(REAL32, 0.0),
    "MPC_XY_CRUISE": ParamSpec(REAL32, 5.0),
    "MPC_ACC_HOR": ParamSpec(REAL32, 3.0),
    "MPC_Z_V_AUTO_UP": ParamSpec(REAL32, 3.0),
    "MPC_Z_V_AUTO_DN": ParamSpec(REAL32, 1.5),
    "MPC_TKO_SPEED": ParamSpec(REAL32, 1.5),
    "NAV_ACC_RAD": ParamSpec(REAL32, 2.0),
    "NAV_MC_ALT_RAD": ParamSpec(REAL32, 0.8),
    "MIS_YAW_ERR": ParamSpec(REAL32, 12.0),
}

#: What a vehicle carrying the payload (camera and gimbal) is configured with: ArduPilot's
#: camera and mount backends (CAM1_TYPE 1 Servo, MNT1_TYPE 1 Servo), PX4's gimbal manager on
#: gimbal protocol v2 input (MNT_MODE_IN 4) with an AUX-driven gimbal of ±90° pitch
#: (MNT_RANGE_PITCH 180); PX4's camera is its own MAVLink component (no parameter).
PAYLOAD: dict[str, dict[str, float]] = {
    "ardupilot": {"CAM1_TYPE": 1, "MNT1_TYPE": 1},
    "px4": {"MNT_MODE_IN": 4, "MNT_MODE_OUT": 0, "MNT_RANGE_PITCH": 180.0},
}

#: What the README's set-up changes from the firmware defaults, per flavour (the pre-flight
#: rules of :mod:`agent.flight.preflight` pass on it).
INDOOR: dict[str, dict[str, float]] = {
    "ardupilot": {"VISO_TYPE": 1, "EK3_SRC1_POSXY": 6, "EK3_SRC1_POSZ": 6, "EK3_SRC1_YAW": 6,
                  "EK3_SRC1_VELXY": 0, "EK3_SRC1_VELZ": 0},
    "px4": {"EKF2_EV_CTRL": 11, "EKF2_HGT_REF": 3, "COM_OBL_RC_ACT": 4},
}

_INT_RANGE = {INT8: (-128, 127), INT16: (-32768, 32767), INT32: (-(2**31), 2**31 - 1)}


def _int_of(value: float, ptype: int) -> int:
    """ArduPilot's float → integer parameter cast: a small bias against truncation, then the
    type's range (AP_Param::set_float)."""
    lo, hi = _INT_RANGE[ptype]
    return int(min(max(value + math.copysign(0.01, value), lo), hi))


class ParamTable(MutableMapping[str, float]):
    """The autopilot's parameters: name → value (float; integers stored as whole floats).

    Item assignment is the autopilot's own (in-process) write; :meth:`from_wire` /
    :meth:`to_wire` apply the flavour's PARAM_SET / PARAM_VALUE encoding (integers byte-wise
    when its agent-side flavour says ``bytewise_params``). The table, the values set from the
    simulated vehicle and the indoor and payload set-ups are the ``flavour``'s
    (:mod:`groundstation.vehicle.flavours`).
    """

    def __init__(self, params: VehicleParams, sysid: int, flavour: SimFlavour) -> None:
        self.bytewise = flavour.autopilot.bytewise_params
        self.specs = dict(flavour.param_specs)
        self._values = {n: float(s.default) for n, s in self.specs.items()}
        start = flavour.initial_values(params, sysid)
        if set(start) - set(self.specs):
            raise ValueError(f"{flavour.name}: initial values of unknown parameters "
                             f"{sorted(set(start) - set(self.specs))}")
        self._values.update(start)
        if params.indoor:
            for name, value in flavour.indoor_params.items():
                self[name] = value
        if params.payload:
            for name, value in flavour.payload_params.items():
                self[name] = value
        for name, value in params.params.items():
            if name not in self.specs:
                raise ValueError(f"unknown {params.autopilot} parameter {name!r}")
            self[name] = value

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    def __setitem__(self, name: str, value: float) -> None:
        spec = self.specs.get(name)
        if spec is None:
            raise KeyError(name)
        v = float(value)
        self._values[name] = float(_int_of(v, spec.type)) if spec.type != REAL32 else v

    def __delitem__(self, name: str) -> None:
        raise TypeError("autopilot parameters cannot be deleted")

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def index(self, name: str) -> int:
        """The parameter's param_index."""
        return list(self._values).index(name)

    def name_at(self, index: int) -> str | None:
        """The name at param_index (None if out of range)."""
        names = list(self._values)
        return names[index] if 0 <= index < len(names) else None

    def from_wire(self, name: str, wire_value: float) -> bool:
        """PARAM_SET: store ``wire_value`` as this flavour reads it; False if not finite or
        unknown (ArduPilot refuses NaN/inf; PX4 takes the raw bytes for int32)."""
        spec = self.specs.get(name)
        if spec is None:
            return False
        if self.bytewise and spec.type == INT32:
            self._values[name] = float(struct.unpack("<i", struct.pack("<f", wire_value))[0])
            return True
        if not math.isfinite(wire_value):
            return False
        self[name] = wire_value
        return True

    def to_wire(self, name: str) -> tuple[float, int]:
        """PARAM_VALUE (param_value, param_type): PX4 int32 byte-wise, ArduPilot a float cast."""
        spec = self.specs[name]
        value = self._values[name]
        if self.bytewise and spec.type == INT32:
            return struct.unpack("<f", struct.pack("<i", int(value)))[0], INT32
        return value, spec.type
