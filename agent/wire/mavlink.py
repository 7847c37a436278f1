"""The MAVLink side of the wire contract: pymavlink loaded for MAVLink 2, the constants both our
driver and our simulated vehicle speak, and the autopilots themselves: one :class:`Autopilot`
object per flavour, registered by name (:func:`flavour`, :func:`register`). Every fact that
depends on the autopilot lives in its flavour object; the flight code
(:mod:`agent.flight.flavours` re-exports this), the settings (:mod:`agent.config.flight`), the
plan export and the simulated vehicles (:mod:`groundstation.vehicle.flavours`, built from these
objects) ask it, and never branch on the autopilot's name. ``docs/autopilots.md`` says how to
add a flavour. The registry lives at this layer so that the settings can name the known ones.

``MAVLINK20=1`` must be set before pymavlink loads its dialect: import ``mavutil`` and
``mavlink`` from here, never from pymavlink directly.

Facts, from the autopilots' own sources:

* ArduCopter (``MAV_AUTOPILOT_ARDUPILOTMEGA`` 3): modes are ``Mode::Number``
  (ArduCopter/mode.h); we fly GUIDED_NOGPS (20), land with LAND (9). SET_ATTITUDE_TARGET
  thrust is a climb rate unless GUID_OPTIONS bit 3 (8) is set, which engage sets and
  confirms. Parameters arrive as floats. Cameras: MAV_CMD_DO_DIGICAM_CONTROL in every
  version (libraries/AP_Camera, ``handle_command``), CAMERA_FEEDBACK after each picture
  (``AP_Camera_Backend::send_camera_feedback``). Fence: FENCE_ENABLE, FENCE_ACTION (0 =
  report only), FENCE_TYPE bits (1 max altitude, 2 circle, 4 polygon, 8 min altitude),
  FENCE_ALT_MAX [m above home]; breaches in FENCE_STATUS and SYS_STATUS (GEOFENCE health).
* PX4 (``MAV_AUTOPILOT_PX4`` 12): custom_mode carries the main mode in bits 16-23 and the
  AUTO sub mode in bits 24-31 (px4_custom_mode.h); we fly OFFBOARD (6), which PX4 only
  enters when set-points already stream; land with AUTO.LAND (4, 6). Integer parameters
  arrive byte-wise in the float field. No DIGICAM fallback: cameras speak the camera
  protocol (PX4 streams CAMERA_IMAGE_CAPTURED from ``camera_capture``). Fence: GF_ACTION
  (0 none, 1 warning, 2 hold, 3 return, 4 terminate, 5 land), GF_MAX_VER_DIST [m above
  home]; a breach is a failsafe (commander/failsafe ``geofence_breached`` with the GF_ACTION
  action: a mode change) announced in a STATUSTEXT; PX4 streams no FENCE_STATUS.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import ClassVar, Final, Protocol

os.environ["MAVLINK20"] = "1"

from pymavlink import mavutil

if mavutil.mavlink.WIRE_PROTOCOL_VERSION != "2.0":  # imported earlier without MAVLINK20
    mavutil.set_dialect("ardupilotmega")

mavlink = mavutil.mavlink

#: ArduCopter ``Mode::Number`` (ArduCopter/mode.h); 8, 10 and 12 are unused there.
ARDUCOPTER_MODES: Final[dict[int, str]] = {
    0: "STABILIZE", 1: "ACRO", 2: "ALT_HOLD", 3: "AUTO", 4: "GUIDED", 5: "LOITER", 6: "RTL",
    7: "CIRCLE", 9: "LAND", 11: "DRIFT", 13: "SPORT", 14: "FLIP", 15: "AUTOTUNE",
    16: "POSHOLD", 17: "BRAKE", 18: "THROW", 19: "AVOID_ADSB", 20: "GUIDED_NOGPS",
    21: "SMART_RTL", 22: "FLOWHOLD", 23: "FOLLOW", 24: "ZIGZAG", 25: "SYSTEMID",
    26: "AUTOROTATE", 27: "AUTO_RTL", 28: "TURTLE",
}
#: The ArduCopter modes the simulated vehicle flies (name → ``custom_mode``), AUTO aside.
ARDUPILOT_MODES: Final = {name: number for number, name in ARDUCOPTER_MODES.items()
                          if name in ("STABILIZE", "ALT_HOLD", "GUIDED", "LOITER", "RTL",
                                      "LAND", "BRAKE", "GUIDED_NOGPS")}
#: PX4 main modes (PX4_CUSTOM_MAIN_MODE_*); 8 was RATTITUDE (now legacy), 9 is reserved.
PX4_MAIN_MODES: Final[dict[int, str]] = {
    1: "MANUAL", 2: "ALTCTL", 3: "POSCTL", 4: "AUTO", 5: "ACRO", 6: "OFFBOARD",
    7: "STABILIZED", 8: "RATTITUDE", 10: "TERMINATION",
}
#: PX4 AUTO sub modes (PX4_CUSTOM_SUB_MODE_AUTO_*); 7 was RTGS (removed).
PX4_AUTO_SUB_MODES: Final[dict[int, str]] = {
    1: "READY", 2: "TAKEOFF", 3: "LOITER", 4: "MISSION", 5: "RTL", 6: "LAND",
    8: "FOLLOW_TARGET", 9: "PRECLAND", 10: "VTOL_TAKEOFF",
}
PX4_MAIN_AUTO: Final = 4

#: ArduCopter GUID_OPTIONS bit 3: SET_ATTITUDE_TARGET thrust is thrust, not a climb rate.
GUID_OPTIONS_REAL_THRUST: Final = 8

#: MAV_CMD_COMPONENT_ARM_DISARM param2 that forces a disarm in flight.
FORCE_DISARM_MAGIC: Final = 21196


def px4_custom_mode(main: int, sub: int = 0) -> int:
    """PX4 HEARTBEAT ``custom_mode`` of (main, sub): main in bits 16-23, sub in bits 24-31."""
    return (main << 16) | (sub << 24)


class EngageSteps(Protocol):
    """What a flavour may do while engaging or landing (implemented by the supervisor)."""

    def set_mode(self, main: int, sub: int = 0) -> None:
        """MAV_CMD_DO_SET_MODE, confirmed by COMMAND_ACK and HEARTBEAT (FlightError if not)."""

    def ensure_param_bits(self, name: str, bits: int) -> None:
        """Read ``name``, OR in ``bits``, write it and confirm it (FlightError if not)."""

    def wait_streaming(self, seconds: float) -> None:
        """Let the set-point stream run for ``seconds`` [s sim] before the next step."""

    @property
    def set_guid_options(self) -> bool:
        """Whether the driver may set ArduCopter's GUID_OPTIONS bit 3 itself."""

    @property
    def prestream_s(self) -> float:
        """How long set-points stream before a flavour's stream-gated mode (PX4 OFFBOARD)."""


class Autopilot(Protocol):
    """One autopilot's conventions: the contract every flavour implements whole
    (``tests/test_autopilot_flavours.py`` checks it). ``name`` is the flavour's name in
    settings and on the command line."""

    name: str
    mav_autopilot: int  #: HEARTBEAT.autopilot (MAV_AUTOPILOT); a plan's ``firmwareType``
    hover_param: str  #: the hover thrust parameter (normalised)
    param_family: str  #: whose parameters it has: the pre-flight rules of that name apply
    bytewise_params: bool  #: integer PARAM_VALUEs copied byte-wise into the float
    digicam_fallback: bool  #: MAV_CMD_DO_DIGICAM_CONTROL triggers its camera
    fence_enable_params: tuple[str, ...]  #: read by the fence pre-flight rules
    fence_alt_param: str  #: maximum altitude above home [m]
    fence_type_bits: tuple[str, int]  #: (parameter, bits) that enable polygon + alt max
    fence_status_message: bool  #: it streams FENCE_STATUS
    #: a mission's gimbal items need MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE first (the autopilot
    #: takes the gimbal's primary control: PX4's src/modules/gimbal/input_mavlink.cpp)
    mission_gimbal_configure: bool
    #: a mission item MAV_CMD_SET_CAMERA_MODE (image) is carried out (PX4's navigator takes
    #: it in a mission, as QGroundControl's camera section writes it; not claimed for
    #: ArduPilot, whose mission support for it is not checked here)
    mission_camera_mode: bool
    control_mode: str  #: the mode we fly it in (a name of :meth:`mode_args`)
    land_mode: str  #: its own landing mode

    def mode_args(self, name: str) -> tuple[int, int]:
        """(main, sub) of the mode called ``name``, as :meth:`set_mode_params` takes them
        (ValueError for a name it does not have)."""

    def custom_mode(self, name: str) -> int:
        """The HEARTBEAT custom_mode of the mode called ``name``."""

    def mode_key(self, custom_mode: int) -> int:
        """The comparable part of a custom_mode."""

    def mode_name(self, custom_mode: int) -> str:
        """Human name of a custom_mode (unknown numbers spelled out)."""

    def set_mode_params(self, main: int, sub: int = 0) -> tuple[list[float], int]:
        """(MAV_CMD_DO_SET_MODE param1.., the custom_mode the HEARTBEAT must then show)."""

    def control_modes(self) -> list[int]:
        """The custom_modes we fly the vehicle in."""

    def in_control_mode(self, custom_mode: int) -> bool:
        """The vehicle is in a mode we fly it in."""

    def engage(self, steps: EngageSteps) -> None:
        """The steps before arming: the flavour's parameters, then our mode."""

    def land(self, steps: EngageSteps) -> None:
        """Command the autopilot's own landing mode."""


class Modes:
    """What every flavour derives from its mode table (a base for :class:`ArduPilot` and
    :class:`PX4`; ``mode_args``, ``set_mode_params`` and ``mode_key`` are the flavour's)."""

    control_mode: str
    land_mode: str

    def mode_args(self, name: str) -> tuple[int, int]:
        raise NotImplementedError

    def set_mode_params(self, main: int, sub: int = 0) -> tuple[list[float], int]:
        raise NotImplementedError

    def mode_key(self, custom_mode: int) -> int:
        raise NotImplementedError

    def custom_mode(self, name: str) -> int:
        return self.set_mode_params(*self.mode_args(name))[1]

    def control_modes(self) -> list[int]:
        return [self.custom_mode(self.control_mode)]

    def in_control_mode(self, custom_mode: int) -> bool:
        return self.mode_key(custom_mode) in {self.mode_key(m) for m in self.control_modes()}

    def land(self, steps: EngageSteps) -> None:
        steps.set_mode(*self.mode_args(self.land_mode))


def _number(table: Mapping[int, str], name: str, what: str) -> int:
    """The number of ``name`` in a number → name table (ValueError, one line, if absent)."""
    for number, known in table.items():
        if known == name:
            return number
    raise ValueError(f"{what} has no mode {name!r}")


class ArduPilot(Modes):
    """ArduCopter: GUIDED_NOGPS with GUID_OPTIONS bit 3 (real thrust); LAND to land."""

    name = "ardupilot"
    mav_autopilot = int(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)
    hover_param = "MOT_THST_HOVER"
    param_family = "ardupilot"
    bytewise_params = False
    digicam_fallback = True
    fence_enable_params: tuple[str, ...] = ("FENCE_ENABLE", "FENCE_ACTION", "FENCE_TYPE")
    fence_alt_param = "FENCE_ALT_MAX"
    fence_type_bits = ("FENCE_TYPE", 1 | 4)  # max altitude + polygon
    fence_status_message = True
    mission_gimbal_configure = False
    mission_camera_mode = False
    control_mode = "GUIDED_NOGPS"
    land_mode = "LAND"
    #: ``custom_mode`` → name (a flavour derived from this one may number them otherwise)
    modes: ClassVar[Mapping[int, str]] = ARDUCOPTER_MODES

    def mode_args(self, name: str) -> tuple[int, int]:
        return _number(self.modes, name, self.name), 0

    def mode_key(self, custom_mode: int) -> int:
        return custom_mode

    def mode_name(self, custom_mode: int) -> str:
        return self.modes.get(custom_mode, f"MODE_{custom_mode}")

    def set_mode_params(self, main: int, sub: int = 0) -> tuple[list[float], int]:
        return [float(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(main)], main

    def engage(self, steps: EngageSteps) -> None:
        if steps.set_guid_options:
            steps.ensure_param_bits("GUID_OPTIONS", GUID_OPTIONS_REAL_THRUST)
        steps.set_mode(*self.mode_args(self.control_mode))


class PX4(Modes):
    """PX4: OFFBOARD after ``prestream_s`` of set-points; AUTO.LAND to land. Mode names are
    the main mode's, ``AUTO.<sub mode>`` in AUTO."""

    name = "px4"
    mav_autopilot = int(mavlink.MAV_AUTOPILOT_PX4)
    hover_param = "MPC_THR_HOVER"
    param_family = "px4"
    bytewise_params = True
    digicam_fallback = False
    fence_enable_params: tuple[str, ...] = ("GF_ACTION",)
    fence_alt_param = "GF_MAX_VER_DIST"
    fence_type_bits = ("", 0)  # PX4 enforces every uploaded fence item
    fence_status_message = False
    mission_gimbal_configure = True
    mission_camera_mode = True
    control_mode = "OFFBOARD"
    land_mode = "AUTO.LAND"

    def mode_args(self, name: str) -> tuple[int, int]:
        main, _, sub = name.partition(".")
        number = _number(PX4_MAIN_MODES, main, self.name)
        return number, _number(PX4_AUTO_SUB_MODES, sub, self.name) if sub else 0

    def mode_key(self, custom_mode: int) -> int:
        return custom_mode & 0xFFFF0000  # bits 0-15 are not part of the mode

    def mode_name(self, custom_mode: int) -> str:
        main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
        name = PX4_MAIN_MODES.get(main, f"MAIN_{main}")
        if main == PX4_MAIN_AUTO:
            return f"{name}.{PX4_AUTO_SUB_MODES.get(sub, f'SUB_{sub}')}"
        return name

    def set_mode_params(self, main: int, sub: int = 0) -> tuple[list[float], int]:
        flags = float(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
        return [flags, float(main), float(sub)], px4_custom_mode(main, sub)

    def engage(self, steps: EngageSteps) -> None:
        steps.wait_streaming(steps.prestream_s)
        steps.set_mode(*self.mode_args(self.control_mode))


#: Every flavour by name (:func:`register` adds one).
FLAVOURS: Final[dict[str, Autopilot]] = {}


def register(autopilot: Autopilot) -> Autopilot:
    """Add a flavour (ValueError if its name is taken); returns it."""
    if autopilot.name in FLAVOURS:
        raise ValueError(f"autopilot {autopilot.name!r} is registered already")
    FLAVOURS[autopilot.name] = autopilot
    return autopilot


def unregister(name: str) -> None:
    """Remove the flavour called ``name`` (e.g. one a test registered)."""
    FLAVOURS.pop(name, None)


def flavour(name: str) -> Autopilot:
    """The flavour called ``name``; ValueError (one line, naming the known ones) otherwise."""
    try:
        return FLAVOURS[name]
    except KeyError:
        raise ValueError(f"autopilot must be one of {', '.join(FLAVOURS)}, got {name!r}") \
            from None


def flavour_of_heartbeat(mav_autopilot: int) -> Autopilot | None:
    """The first registered flavour whose HEARTBEAT.autopilot is ``mav_autopilot`` (None:
    not one we fly)."""
    return next((f for f in FLAVOURS.values() if f.mav_autopilot == mav_autopilot), None)


def flavour_names() -> tuple[str, ...]:
    """The flavours' names, e.g. for a command-line choice."""
    return tuple(FLAVOURS)


register(ArduPilot())
register(PX4())

__all__ = [
    "ARDUCOPTER_MODES",
    "ARDUPILOT_MODES",
    "FLAVOURS",
    "FORCE_DISARM_MAGIC",
    "GUID_OPTIONS_REAL_THRUST",
    "PX4",
    "PX4_AUTO_SUB_MODES",
    "PX4_MAIN_AUTO",
    "PX4_MAIN_MODES",
    "ArduPilot",
    "Autopilot",
    "EngageSteps",
    "Modes",
    "flavour",
    "flavour_names",
    "flavour_of_heartbeat",
    "mavlink",
    "mavutil",
    "px4_custom_mode",
    "register",
    "unregister",
]
