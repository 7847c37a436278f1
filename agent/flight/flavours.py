"""Autopilot flavours: one class per autopilot behind one :class:`Autopilot` protocol, so the
rest of the flight side never branches on the autopilot's name.

A flavour knows its flight modes (HEARTBEAT ``custom_mode`` numbers and names), how to put
the vehicle under our control (``engage``: the steps before arming), how to land it, how its
parameters travel (PARAM_VALUE encoding), which parameters the pre-flight rules and the fence
need, and how it reports a fence breach. Facts, from the autopilots' own sources:

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

from typing import Final, Protocol

from agent.wire.mavlink import (
    ARDUPILOT_GUIDED_NOGPS,
    ARDUPILOT_LAND,
    GUID_OPTIONS_REAL_THRUST,
    PX4_AUTO_LAND,
    PX4_OFFBOARD,
    mavlink,
)

#: ArduCopter ``Mode::Number`` (ArduCopter/mode.h); 8, 10 and 12 are unused there.
ARDUCOPTER_MODES: Final[dict[int, str]] = {
    0: "STABILIZE", 1: "ACRO", 2: "ALT_HOLD", 3: "AUTO", 4: "GUIDED", 5: "LOITER", 6: "RTL",
    7: "CIRCLE", 9: "LAND", 11: "DRIFT", 13: "SPORT", 14: "FLIP", 15: "AUTOTUNE",
    16: "POSHOLD", 17: "BRAKE", 18: "THROW", 19: "AVOID_ADSB", 20: "GUIDED_NOGPS",
    21: "SMART_RTL", 22: "FLOWHOLD", 23: "FOLLOW", 24: "ZIGZAG", 25: "SYSTEMID",
    26: "AUTOROTATE", 27: "AUTO_RTL", 28: "TURTLE",
}
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


def px4_custom_mode(main: int, sub: int = 0) -> int:
    """PX4 HEARTBEAT custom_mode of (main, sub): main in bits 16-23, sub in bits 24-31."""
    return ((main & 0xFF) << 16) | ((sub & 0xFF) << 24)


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
        """How long set-points stream before PX4's OFFBOARD switch [s sim]."""


class Autopilot(Protocol):
    """One autopilot's conventions. ``name`` is the flavour's name in settings and rules."""

    name: str
    mav_autopilot: int  #: HEARTBEAT.autopilot (MAV_AUTOPILOT)
    hover_param: str  #: the hover thrust parameter (normalised)
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


class ArduPilot:
    """ArduCopter: GUIDED_NOGPS with GUID_OPTIONS bit 3 (real thrust); LAND to land."""

    name = "ardupilot"
    mav_autopilot = int(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)
    hover_param = "MOT_THST_HOVER"
    bytewise_params = False
    digicam_fallback = True
    fence_enable_params: tuple[str, ...] = ("FENCE_ENABLE", "FENCE_ACTION", "FENCE_TYPE")
    fence_alt_param = "FENCE_ALT_MAX"
    fence_type_bits = ("FENCE_TYPE", 1 | 4)  # max altitude + polygon
    fence_status_message = True
    mission_gimbal_configure = False
    mission_camera_mode = False

    def mode_key(self, custom_mode: int) -> int:
        return custom_mode

    def mode_name(self, custom_mode: int) -> str:
        return ARDUCOPTER_MODES.get(custom_mode, f"MODE_{custom_mode}")

    def set_mode_params(self, main: int, sub: int = 0) -> tuple[list[float], int]:
        return [float(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(main)], main

    def control_modes(self) -> list[int]:
        return [ARDUPILOT_GUIDED_NOGPS]

    def in_control_mode(self, custom_mode: int) -> bool:
        return custom_mode == ARDUPILOT_GUIDED_NOGPS

    def engage(self, steps: EngageSteps) -> None:
        if steps.set_guid_options:
            steps.ensure_param_bits("GUID_OPTIONS", GUID_OPTIONS_REAL_THRUST)
        steps.set_mode(ARDUPILOT_GUIDED_NOGPS)

    def land(self, steps: EngageSteps) -> None:
        steps.set_mode(ARDUPILOT_LAND)


class PX4:
    """PX4: OFFBOARD after ``prestream_s`` of set-points; AUTO.LAND to land."""

    name = "px4"
    mav_autopilot = int(mavlink.MAV_AUTOPILOT_PX4)
    hover_param = "MPC_THR_HOVER"
    bytewise_params = True
    digicam_fallback = False
    fence_enable_params: tuple[str, ...] = ("GF_ACTION",)
    fence_alt_param = "GF_MAX_VER_DIST"
    fence_type_bits = ("", 0)  # PX4 enforces every uploaded fence item
    fence_status_message = False
    mission_gimbal_configure = True
    mission_camera_mode = True

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

    def control_modes(self) -> list[int]:
        return [px4_custom_mode(*PX4_OFFBOARD)]

    def in_control_mode(self, custom_mode: int) -> bool:
        return self.mode_key(custom_mode) == px4_custom_mode(*PX4_OFFBOARD)

    def engage(self, steps: EngageSteps) -> None:
        steps.wait_streaming(steps.prestream_s)
        steps.set_mode(*PX4_OFFBOARD)

    def land(self, steps: EngageSteps) -> None:
        steps.set_mode(*PX4_AUTO_LAND)


#: Every flavour by name.
FLAVOURS: Final[dict[str, Autopilot]] = {"ardupilot": ArduPilot(), "px4": PX4()}


def flavour(name: str) -> Autopilot:
    """The flavour called ``name`` ('ardupilot' or 'px4'); ValueError (one line) otherwise."""
    try:
        return FLAVOURS[name]
    except KeyError:
        raise ValueError(f"autopilot must be one of {', '.join(FLAVOURS)}, got {name!r}") \
            from None


def flavour_of_heartbeat(mav_autopilot: int) -> Autopilot | None:
    """The flavour whose HEARTBEAT.autopilot is ``mav_autopilot`` (None: not one we fly)."""
    return next((f for f in FLAVOURS.values() if f.mav_autopilot == mav_autopilot), None)


def flavour_names() -> tuple[str, ...]:
    """The flavours' names, e.g. for a command-line choice."""
    return tuple(FLAVOURS)


__all__ = ["ARDUCOPTER_MODES", "FLAVOURS", "PX4", "PX4_AUTO_SUB_MODES", "PX4_MAIN_AUTO",
           "PX4_MAIN_MODES", "ArduPilot", "Autopilot", "EngageSteps", "flavour",
           "flavour_names", "flavour_of_heartbeat", "px4_custom_mode"]
