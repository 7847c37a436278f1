"""The contract of a simulated autopilot's flavour: every choice the simulated vehicle makes
differently per autopilot, asked of one :class:`SimFlavour` object (``Autopilot.flavour``)
instead of a branch on the autopilot's name.

A :class:`SimFlavour` is built from the agent's flavour object (:mod:`agent.wire.mavlink`:
name, HEARTBEAT id, mode numbers, hover-thrust parameter, PARAM_VALUE encoding...), which it
keeps as ``autopilot``; mode numbers always come from it. Members, by subsystem, each with
the module of :mod:`groundstation.vehicle` whose docstring gives the autopilots' sources:

* identity, wire and streams (``telemetry``, ``inbound``, ``conventions``);
* parameters (``params``);
* modes, arming, takeoff, SYS_STATUS and HEARTBEAT (``modes``, ``autopilot``);
* the set-point controllers (``control``), the EKF's source (``ekf``);
* failsafes, battery, fence (``failsafe``, ``battery``, ``fence``);
* gimbal and camera (``gimbal``, ``camera``);
* missions: ``mission_class``, a ``mission_exec.MissionExec`` subclass with its
  ``mission_fly.Flight`` subclass (their own abstract methods and class attributes).

Methods take the vehicle (``ap``: :class:`groundstation.vehicle.autopilot.Autopilot`) or the
subsystem they decide for. ``tests/test_autopilot_flavours.py`` checks that every registered
flavour implements all of it; ``docs/autopilots.md`` says how to add one.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from typing import Any

from agent.wire.mavlink import Autopilot

Params = Mapping[str, float]


class SimFlavour(ABC):
    """One autopilot's simulated behaviour (module docstring). Attributes are set by the
    subclass (class attributes, or in ``__init__`` from ``autopilot``'s mode numbers)."""

    # -- identity, wire, streams ----------------------------------------------------------
    autopilot: Autopilot  #: the agent-side flavour this simulates
    sitl_origin: tuple[float, float, float]  #: default EKF origin: lat, lon [deg], alt [m]
    sw_version: int  #: AUTOPILOT_VERSION.flight_sw_version
    version_capabilities: int  #: its MAV_PROTOCOL_CAPABILITY bits beyond the common ones
    legacy_data_streams: bool  #: REQUEST_DATA_STREAM changes its streams
    streams_odometry: bool  #: it sends ODOMETRY (on request)
    fuses_att_pos_mocap: bool  #: its EKF takes ATT_POS_MOCAP as external navigation
    # -- parameters -----------------------------------------------------------------------
    param_specs: Mapping[str, Any]  #: name → ``params.ParamSpec``, in index order
    indoor_params: Params  #: what the README's indoor set-up changes
    payload_params: Params  #: what carrying the camera and gimbal sets
    #: what the field set-up (``viscover groundstation --gnss``) sets: the pre-flight fence
    #: rules pass on it
    field_params: Params
    # -- modes ----------------------------------------------------------------------------
    refused: int  #: MAV_RESULT of a refused mode change or arming
    initial_mode: int  #: custom_mode at boot
    kinds: Mapping[int, str]  #: custom_mode → behaviour (``modes.KINDS``)
    known_modes: frozenset[int]  #: the modes it takes
    needs_position: frozenset[int]  #: modes that need a position once armed (and to arm)
    stream_gated_modes: frozenset[int]  #: modes entered only with a fresh set-point
    position_guided_modes: frozenset[int]  #: guided modes holding position until a set-point
    no_arm_kinds: frozenset[str]  #: mode kinds that refuse arming
    land_mode: int  #: MAV_CMD_NAV_LAND's mode and the failsafes' Land
    rtl_mode: int  #: MAV_CMD_NAV_RETURN_TO_LAUNCH's mode
    hold_mode: int  #: the failsafes' Hold (a pending delayed action waits in it)
    loiter_mode: int  #: loiter over a point (after a takeoff or a mission)
    mission_mode: int  #: flies the stored mission
    home_message_at_arming: bool  #: HOME_POSITION is sent when arming sets home
    # -- set-point control ----------------------------------------------------------------
    min_thrust: float  #: SET_ATTITUDE_TARGET thrust is clamped to [min_thrust, 1]
    partial_body_rates: bool  #: a type_mask ignoring only some body rates is taken
    reinit_on_bad_setpoint: bool  #: a refused set-point re-initialises the angle controller
    yaw_rate_feedforward: bool  #: body_yaw_rate integrates into the yaw set-point
    waits_on_ground: bool  #: landed, it waits for a climb command before lifting off
    # -- gimbal, camera, missions ---------------------------------------------------------
    gimbal_device_id: int  #: gimbal_device_id in the manager's messages
    gimbal_component: int  #: component sending GIMBAL_DEVICE_ATTITUDE_STATUS
    gimbal_attitude_device_id: int  #: gimbal_device_id field of that message
    gimbal_absent_result: int  #: MAV_RESULT of a gimbal command without a gimbal
    gimbal_unset_result: int  #: MAV_RESULT of PITCHYAW with neither angles nor rates
    gimbal_control_to_autopilot: bool  #: CONFIGURE −2 gives control to the autopilot itself
    autopilot_camera_commands: bool  #: the autopilot component takes camera commands
    first_image_index: int  #: index of the first picture since boot
    #: the ``mission_exec.MissionExec`` subclass that flies its missions (with its
    #: ``mission_fly.Flight``): what differs in missions, DO items included
    mission_class: Callable[[Any], Any]

    def __init__(self, autopilot: Autopilot) -> None:
        self.autopilot = autopilot

    @property
    def name(self) -> str:
        """The flavour's name (the agent flavour's)."""
        return self.autopilot.name

    def kind(self, mode: int) -> str:
        """Behaviour of ``mode`` ('idle' for a mode without one here)."""
        return self.kinds.get(mode, "idle")

    # -- wire and streams -----------------------------------------------------------------
    @abstractmethod
    def streams(self, telemetry_rate: float) -> dict[int, float]:
        """Its default streams beyond the common ones: message id → interval [s]."""

    @abstractmethod
    def addressed_to(self, msg: Any, sysid: int) -> bool:
        """Whether the autopilot ``sysid`` processes ``msg``."""

    @abstractmethod
    def arm_request(self, param1: float, param2: float) -> tuple[bool, bool] | None:
        """ARM_DISARM as it reads it: (arm, forced), None for UNSUPPORTED."""

    @abstractmethod
    def heartbeat_state(self, ap: Any) -> tuple[int, int]:
        """HEARTBEAT of the vehicle ``ap``: its base_mode flags beyond CUSTOM_MODE_ENABLED and
        SAFETY_ARMED, and its system_status."""

    @abstractmethod
    def sensor_bits(self, ap: Any, t: float, base: int) -> tuple[int, int, int]:
        """SYS_STATUS (present, enabled, health): the simulated sensors ``base`` plus its
        pre-arm, geofence and vision bits."""

    # -- parameters -----------------------------------------------------------------------
    @abstractmethod
    def initial_values(self, params: Any, sysid: int) -> dict[str, float]:
        """Parameter values set from the simulated vehicle (``params.VehicleParams``):
        system id, hover thrust, speeds, pack, set-point timeout."""

    # -- modes ----------------------------------------------------------------------------
    @abstractmethod
    def requested_mode(self, custom: int, sub: int) -> int:
        """The custom_mode a DO_SET_MODE (param2, param3) or SET_MODE asks for."""

    @abstractmethod
    def reads_sub_mode(self, custom: int) -> bool:
        """DO_SET_MODE's param3 must be a number for main mode ``custom``."""

    @abstractmethod
    def takeoff(self, ap: Any, p: list[float], t: float, frame: int | None) -> int:
        """MAV_CMD_NAV_TAKEOFF (param1..7, COMMAND_INT's frame or None): the MAV_RESULT."""

    @abstractmethod
    def on_setpoint_timeout(self, ap: Any, t: float) -> None:
        """The set-point stream timed out in a guided mode (after the event is recorded)."""

    # -- set-point control ----------------------------------------------------------------
    @abstractmethod
    def setpoint_timeout(self, pt: Params) -> float:
        """How long a set-point lasts [s]."""

    @abstractmethod
    def thrust_is_climb_rate(self, pt: Params) -> bool:
        """SET_ATTITUDE_TARGET thrust is read as a climb rate."""

    @abstractmethod
    def land_speed(self, pt: Params) -> float:
        """Landing descent speed [m/s]."""

    @abstractmethod
    def disarm_delay(self, pt: Params) -> float:
        """Extra wait after touchdown before the disarm [s]."""

    @abstractmethod
    def rtl_altitude(self, pt: Params) -> float:
        """Return altitude above home [m]."""

    @abstractmethod
    def position_source(self, pt: Params, gnss: bool, vision_fresh: bool) -> str | None:
        """What its EKF's position comes from: 'vision', 'gnss' or None."""

    # -- failsafes, battery, fence --------------------------------------------------------
    @abstractmethod
    def failsafe(self, ap: Any, action: str, t: float) -> None:
        """Carry out failsafe ``action`` (armed, not 'warn') of ``failsafe``."""

    @abstractmethod
    def battery_remaining(self, pt: Params, used: float, soc: float) -> float | None:
        """Remaining charge (0..1, unclamped; None unknown) after ``used`` [mAh] at true
        state of charge ``soc``."""

    @abstractmethod
    def battery_level(self, monitor: Any, reading: Any, t: float) -> int:
        """The failsafe level (MAV_BATTERY_CHARGE_STATE) reached by ``reading``."""

    @abstractmethod
    def battery_action(self, pt: Params, level: int) -> str | None:
        """The failsafe action of a new ``level`` (None: none)."""

    @abstractmethod
    def fence_enabled(self, fence: Any) -> bool:
        """The fence is checked."""

    @abstractmethod
    def fence_enable_command(self, fence: Any, p: list[float]) -> int:
        """MAV_CMD_DO_FENCE_ENABLE: the MAV_RESULT."""

    @abstractmethod
    def fence_bits(self, fence: Any, p: Any, home: Any) -> tuple[int, float]:
        """Breach bits (FENCE_TYPE bits) of position ``p`` and how far out [m]."""

    @abstractmethod
    def fence_action(self, pt: Params, distance: float) -> str | None:
        """The action of a new breach ``distance`` [m] out (None: report only)."""

    # -- gimbal and camera ----------------------------------------------------------------
    @abstractmethod
    def gimbal_present(self, pt: Params) -> bool:
        """A gimbal is configured."""

    @abstractmethod
    def gimbal_limits(self, pt: Params) -> tuple[float, float, float, float, float, float]:
        """(roll_min, roll_max, pitch_min, pitch_max, yaw_min, yaw_max) [rad]."""

    @abstractmethod
    def gimbal_command_refusal(self, gimbal: Any, p: list[float],
                               src: tuple[int, int]) -> int | None:
        """DO_GIMBAL_MANAGER_PITCHYAW (param1..7) from ``src`` refused: its MAV_RESULT (None:
        taken)."""

    @abstractmethod
    def gimbal_message_taken(self, gimbal: Any, m: Any, src: tuple[int, int],
                             angles: tuple[float, float], rates: tuple[float, float]) -> bool:
        """GIMBAL_MANAGER_SET_PITCHYAW ``m`` from ``src`` is taken."""

    @abstractmethod
    def gimbal_device_flags(self, gimbal: Any) -> int:
        """GIMBAL_DEVICE_ATTITUDE_STATUS.flags."""

    @abstractmethod
    def camera_kind(self, ap: Any) -> str:
        """'autopilot' (the autopilot's camera), 'component' (a MAVLink camera), 'none'."""
