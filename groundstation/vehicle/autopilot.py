"""One simulated autopilot (ArduCopter or PX4 flavour) on top of the fleet's dynamics.

Behaviour, each checked against the autopilots' sources (paths below; ``search`` tool):

* Modes. ArduCopter custom modes (ArduCopter/mode.h): STABILIZE, ALT_HOLD, GUIDED, LOITER,
  RTL, LAND, BRAKE, GUIDED_NOGPS. GUIDED, LOITER, RTL and BRAKE need a position estimate
  (``Copter::set_mode``: ``requires_GPS() && !position_ok()``, checked once armed; on the
  ground at arming): here VISO_TYPE > 0, EK3_SRC1_POSXY = 6 and vision/odometry heard within
  1 s. A refused mode or an unknown one is MAV_RESULT_FAILED; a DO_SET_MODE without
  MAV_MODE_FLAG_CUSTOM_MODE_ENABLED is DENIED (GCS_MAVLINK::_set_mode_common). PX4 main/sub
  modes (px4_custom_mode.h): MANUAL, ALTCTL, POSCTL, AUTO.LOITER / RTL / LAND / TAKEOFF,
  OFFBOARD, STABILIZED; refusals are TEMPORARILY_REJECTED (commander). PX4 enters OFFBOARD
  only with a set-point newer than COM_OF_LOSS_T (HealthAndArmingChecks/checks/
  offboardCheck.cpp). Mode rules, arming checks, NAV_TAKEOFF, home and SYS_STATUS health:
  :mod:`groundstation.vehicle.modes`; the EKF origin: :mod:`groundstation.vehicle.conventions`.
* SET_ATTITUDE_TARGET (ArduCopter/GCS_MAVLink_Copter.cpp
  ``handle_message_set_attitude_target``): ignored outside GUIDED/GUIDED_NOGPS (OFFBOARD);
  thrust ignored, a non-unit quaternion (1e-3), non-finite fields or body rates given only
  partly re-initialise the guided angle controller (level, climb rate 0) and are counted.
  ArduCopter reads thrust as a climb rate (0.5 hold, WPNAV_SPEED_UP / _DN at the ends)
  unless GUID_OPTIONS bit 3; on the ground it only takes off for a positive climb rate or
  thrust (``ModeGuided::angle_control_run``). PX4 maps thrust to body −z and may take
  body_yaw_rate as a yaw feed-forward.
* Set-point timeout. ArduCopter: after GUID_TIMEOUT without a set-point it levels (keeps its
  yaw), holds altitude with a climb rate of 0 and stays in GUIDED; thrust mode is left until
  the next set-point (``angle_control_run``). PX4: after COM_OF_LOSS_T the offboard-loss
  failsafe switches mode by COM_OBL_RC_ACT (0 Position, 1 Altitude, 3 Return, 4 Land,
  5 Hold, 6/7 terminate/disarm; without a position estimate Position falls back to Altitude).
* LAND / MAV_CMD_NAV_LAND: level, descend at LAND_SPEED / MPC_LAND_SPEED, disarm once landed
  (ArduCopter's land detector: 1 s on the ground; PX4: COM_DISARM_LAND). RTL /
  MAV_CMD_NAV_RETURN_TO_LAUNCH: climb to RTL_ALT, fly home, land.
* Arming: MAV_CMD_COMPONENT_ARM_DISARM, read as each autopilot reads param1 and param2
  (:func:`groundstation.vehicle.inbound.arm_request`; a NaN param2 is no force); disarming in
  flight only with param2 = 21196; ArduCopter refuses to arm in LAND and RTL (FAILED), PX4
  refuses as TEMPORARILY_REJECTED; both refuse a mode that needs a position without one.
  Home is set at arming.
* Parameters (:mod:`groundstation.vehicle.params`), MAV_CMD_REQUEST_MESSAGE,
  MAV_CMD_SET_MESSAGE_INTERVAL, REQUEST_DATA_STREAM (:mod:`groundstation.vehicle.telemetry`).
* Missions flown in ArduCopter AUTO / PX4 AUTO.MISSION: :mod:`groundstation.vehicle.
  mission_exec` (items, refusals, MISSION_CURRENT / MISSION_ITEM_REACHED).
* Outdoor equipment (:mod:`groundstation.vehicle.devices`): camera, gimbal, fence and
  mission storage, battery monitor and failsafes, GNSS-aided EKF; a PX4 camera is its own
  component (MAV_COMP_ID_CAMERA).
* Commands (:mod:`groundstation.vehicle.commands`): exactly one COMMAND_ACK per command
  addressed to the vehicle, to the sender's system and component (GCS_Common.cpp); unknown
  commands UNSUPPORTED, non-finite or out-of-range parameters DENIED. Messages addressed to
  another system or component are not processed (:func:`~.inbound.addressed_to`). An
  exception that still escapes a handler is counted and logged by the fleet's
  :class:`~.inbound.HandlerGuard`; the vehicle goes on with the next message.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from agent.flight.frames import euler_from_quat, quat_is_unit, quat_normalize
from agent.wire.mavlink import mavlink as mav
from groundstation.vehicle import inbound
from groundstation.vehicle import telemetry as tm
from groundstation.vehicle.commands import Commands
from groundstation.vehicle.control import Controls, VehicleLog
from groundstation.vehicle.devices import MISSION, Devices
from groundstation.vehicle.dynamics import VehicleState
from groundstation.vehicle.flavours import sim_flavour
from groundstation.vehicle.modes import ModeRules
from groundstation.vehicle.params import ParamTable, VehicleParams

_log = logging.getLogger(f"viscover.{__name__}")

#: The messages the vehicle handles → their handler (a method of :class:`Autopilot`).
HANDLERS = {"SET_ATTITUDE_TARGET": "_on_attitude_target", "HEARTBEAT": "_on_heartbeat",
            "COMMAND_LONG": "_on_command", "COMMAND_INT": "_on_command",
            "VISION_POSITION_ESTIMATE": "_on_external_nav", "ODOMETRY": "_on_external_nav",
            "ATT_POS_MOCAP": "_on_external_nav", "PARAM_SET": "_on_param_set",
            "PARAM_REQUEST_READ": "_on_param_request_read",
            "PARAM_REQUEST_LIST": "_on_param_request_list", "SET_MODE": "_on_set_mode",
            "REQUEST_DATA_STREAM": "_on_request_data_stream",
            "GIMBAL_MANAGER_SET_PITCHYAW": "on_gimbal_set_pitchyaw",
            **dict.fromkeys(MISSION, "on_mission")}

class Autopilot(Devices, ModeRules, Commands, Controls):
    """The autopilot of vehicle ``index``: handles its MAVLink, computes its commands.

    ``link`` sends (``link.mav``) and receives (``link.receive()``); ``truth()`` is the
    fleet's current :class:`VehicleState` (the simulated EKF reads it, plus sensor noise).
    """

    def __init__(self, name: str, index: int, sysid: int, params: VehicleParams, link: Any,
                 truth: Callable[[], VehicleState], rng: np.random.Generator,
                 guard: inbound.HandlerGuard | None = None, seed: int = 0) -> None:
        self.name, self.i, self.sysid, self.params = name, index, sysid, params
        self.link, self.truth, self.rng = link, truth, rng
        self.guard = guard or inbound.HandlerGuard()
        self.flavour = sim_flavour(params.autopilot)  # every per-autopilot choice
        self.params_table = ParamTable(params, sysid, self.flavour)
        self.log = VehicleLog()
        self.streams = tm.MessageStreams.for_flavour(self.flavour, params.telemetry_rate)
        self.armed = False
        self.mode = self.flavour.initial_mode
        self.last_vision_t = -math.inf
        self.origin = params.origin or self.flavour.sitl_origin
        self.takeoff_z: float | None = None
        self.cmd_frame: int | None = None
        self.cmd_src = (0, 0)
        self._param_queue: list[str] = []
        self._requested: list[int] = []
        self._interval_replies: list[int] = []
        super().__init__()
        self.init_devices(seed)

    # -- identity -----------------------------------------------------------------------
    @property
    def mav(self) -> mav.MAVLink:
        """The MAVLink encoder of this vehicle's link (system id, component 1)."""
        return self.link.mav

    @property
    def port(self) -> int:
        """UDP port this vehicle listens on."""
        return int(self.link.port)

    @property
    def kind(self) -> str:
        """Behaviour of the current mode (:data:`groundstation.vehicle.modes.KINDS`)."""
        return self.flavour.kind(self.mode)

    @property
    def guided(self) -> bool:
        """In the mode that takes SET_ATTITUDE_TARGET (GUIDED/GUIDED_NOGPS or OFFBOARD)."""
        return self.kind == "guided"

    @property
    def landing(self) -> bool:
        """In LAND (ArduPilot) / AUTO.LAND (PX4)."""
        return self.kind == "land"

    def event(self, t: float, name: str) -> None:
        """Record an event at simulation time t [s]."""
        self.log.events.append((t, name))
        _log.debug("%s t=%.2f %s", self.name, t, name)

    def position_ok(self, t: float) -> bool:
        """The simulated EKF has a position: external navigation configured and heard
        within 1 s (ArduPilot VISO_TYPE + EK3_SRC1_POSXY = 6; PX4 EKF2_EV_CTRL bit 0), or a
        GNSS receiver selected as the source (:mod:`groundstation.vehicle.ekf`)."""
        return self.pose_source(t) is not None

    # -- MAVLink in ---------------------------------------------------------------------
    def poll(self, t: float) -> None:
        """Handle every datagram waiting on the link. A message whose handling still raises
        is counted and logged by the guard, and the next one is handled (last line of
        defence: the handlers answer bad input themselves, see :mod:`.inbound`)."""
        try:
            messages = self.link.receive()
        except Exception as exc:  # a parser bug must not stop the fleet either
            self.guard.failed(self.name, "receiving", exc)
            return
        for msg in messages:
            try:
                self._handle(msg, t)
            except Exception as exc:  # one message must not stop the fleet
                self.guard.failed(self.name, inbound.describe(msg), exc)

    def _handle(self, msg: Any, t: float) -> None:
        if self.route_device(msg, t):
            return
        if not self.flavour.addressed_to(msg, self.sysid):
            return
        name = HANDLERS.get(msg.get_type())
        if name is not None:
            getattr(self, name)(msg, t)

    def _on_heartbeat(self, _msg: Any, _t: float) -> None:
        self.log.heartbeats_rx += 1

    def _on_external_nav(self, msg: Any, t: float) -> None:
        """VISION_POSITION_ESTIMATE, ODOMETRY, ATT_POS_MOCAP: the simulated EKF's fusion."""
        kind = msg.get_type()
        if kind == "ODOMETRY":
            self.log.odometry += 1
        elif kind == "VISION_POSITION_ESTIMATE":
            self.log.vision += 1
        # PX4's EKF2 does not take ATT_POS_MOCAP; ArduPilot does (facts.md).
        if kind != "ATT_POS_MOCAP" or self.flavour.fuses_att_pos_mocap:
            self.last_vision_t = t
        self.log.last_vision_wall = time.monotonic()

    def _on_param_set(self, msg: Any, _t: float) -> None:
        name = str(msg.param_id)
        if self.params_table.from_wire(name, float(msg.param_value)):
            self.send_param(name)

    def _on_param_request_read(self, msg: Any, _t: float) -> None:
        idx = int(msg.param_index)
        found = self.params_table.name_at(idx) if idx >= 0 else str(msg.param_id)
        if found is not None and found in self.params_table:
            self.send_param(found)

    def _on_param_request_list(self, _msg: Any, _t: float) -> None:
        self._param_queue = list(self.params_table)

    def _on_set_mode(self, msg: Any, t: float) -> None:
        self._set_mode(int(msg.base_mode), int(msg.custom_mode), t)

    def _on_request_data_stream(self, msg: Any, t: float) -> None:
        if self.flavour.legacy_data_streams:  # ArduPilot's groups; PX4 ignores the message
            self.streams.request_data_stream(int(msg.req_stream_id),
                                             float(msg.req_message_rate),
                                             bool(msg.start_stop), t)

    def send_param(self, name: str) -> None:
        """PARAM_VALUE of ``name``, typed and encoded as this flavour does."""
        value, ptype = self.params_table.to_wire(name)
        self.mav.param_value_send(name.encode(), value, ptype, len(self.params_table),
                                  self.params_table.index(name))

    def _on_attitude_target(self, m: Any, t: float) -> None:
        """SET_ATTITUDE_TARGET (module docstring)."""
        q = np.array(m.q, dtype=np.float64)
        thrust, yaw_rate, mask = float(m.thrust), float(m.body_yaw_rate), int(m.type_mask)
        rates = (float(m.body_roll_rate), float(m.body_pitch_rate), yaw_rate)
        self.sp_recent.append(t)
        self.log.setpoint_times.append(time.monotonic())
        if not self.guided:
            self.log.rejected_mode += 1
            return
        rate_bits = mask & 7
        if not (np.all(np.isfinite(q)) and math.isfinite(thrust)
                and all(math.isfinite(r) for r in rates)):
            self.log.rejected_nonfinite += 1
            self._reinit_guided(t, "rejected_nonfinite")
            return
        if mask & 128 == 0 and not quat_is_unit(q):
            self.log.rejected_quat += 1
            self._reinit_guided(t, "rejected_quaternion")
            return
        if mask & 64 or mask & 128 or (not self.flavour.partial_body_rates
                                       and rate_bits not in (0, 7)):
            self.log.rejected_mask += 1  # thrust ignored, rates only, or rates in part
            self._reinit_guided(t, "rejected_type_mask")
            return
        roll, pitch, yaw = euler_from_quat(quat_normalize(q))
        self.accept_setpoint(t, (roll, pitch, yaw), thrust, yaw_rate if mask & 4 == 0 else None)
        self.log.last_thrust, self.log.last_q, self.log.last_type_mask = thrust, q, mask

    def _arm(self, arm: bool, force: bool, t: float) -> int:
        """Arm or disarm (``force``: param2 = 21196, disarm in flight). Refusals: ArduCopter
        MAV_RESULT_FAILED (GCS_Common.cpp), PX4 TEMPORARILY_REJECTED (Commander.cpp)."""
        refused = int(self.flavour.refused)
        state = self.truth()
        if arm:
            if not self.armed and self.kind in self.flavour.no_arm_kinds:
                return refused  # ArduCopter: LAND and RTL do not allow arming
            if not self.armed and self.mission.refuses_arming():
                self.event(t, "arming_refused_mission_mode")
                return refused
            if not self.armed and not self.arming_check(t):
                self.event(t, "arming_refused_no_position")
                return refused
            if not self.armed:
                self.armed = True
                self.ground_since = t
                self.sp_t = max(self.sp_t, t)  # the set-point timeout starts at arming
                self.home = state.p[self.i].copy()
                self.event(t, "armed")
                if self.flavour.home_message_at_arming:
                    self._requested.append(tm.HOME_POSITION)
            return int(mav.MAV_RESULT_ACCEPTED)
        if self.armed and not (self.on_ground() or force):
            return refused
        if self.armed:
            self.armed = False
            self.event(t, "disarmed")
        return int(mav.MAV_RESULT_ACCEPTED)

    def enter_mode(self, new: int, t: float) -> None:
        """Switch to mode ``new`` (no checks) and start its controller (and the mission's
        when it is the mission mode: :mod:`groundstation.vehicle.mission_exec`)."""
        was_auto = self.kind == "auto"
        self.mode = new
        self.failsafe = False
        self.sp_t = t  # grace period: a fresh mode starts its set-point timeout now
        self.start_mode(t)
        if was_auto:
            self.mission.on_exit(t)
        if self.kind == "auto":
            self.mission.on_enter(t)
        self.event(t, "mode_land" if self.landing else f"mode_{new}")
        if self.landing:
            self.event(t, "land")

    def on_setpoint_timeout(self, t: float) -> None:
        """The flavour's set-point timeout (module docstring): PX4's offboard-loss failsafe;
        ArduCopter stays in GUIDED."""
        self.event(t, "setpoint_timeout")
        self.flavour.on_setpoint_timeout(self, t)

    # -- MAVLink out --------------------------------------------------------------------
    def telemetry(self, t: float) -> None:
        """Send the streams that are due, requested messages and queued parameters (a failure
        is the guard's: this vehicle must not silence the others). The equipment
        (:meth:`supervise`: gimbal, camera, fence, battery, failsafes) runs first."""
        try:
            self.supervise(t)
        except Exception as exc:
            self.guard.failed(self.name, "supervising its equipment", exc)
        try:
            for msgid in self.streams.due(t) + self._requested:
                tm.encode(self, msgid, t)
            for name in self._param_queue[:50]:
                self.send_param(name)
        except Exception as exc:
            self.guard.failed(self.name, "sending telemetry", exc)
        self._requested.clear()
        del self._param_queue[:50]

    def heartbeat_fields(self) -> tuple[int, int, int]:
        """(base_mode, custom_mode, system_status) as each autopilot builds them: ArduCopter
        GCS_MAVLINK_Copter::base_mode / vehicle_system_status, PX4
        get_mavlink_navigation_mode / get_mavlink_mode_state (mavlink_messages.cpp)."""
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self.armed:
            base |= mav.MAV_MODE_FLAG_SAFETY_ARMED
        flags, status = self.flavour.heartbeat_state(self)
        return base | flags, self.mode, status

    def landed_state(self) -> int:
        """MAV_LANDED_STATE (GCS_MAVLINK_Copter::landed_state; PX4 land detector)."""
        if self.landed or not self.armed:
            return int(mav.MAV_LANDED_STATE_ON_GROUND)
        if self.kind == "land" or (self.kind == "auto" and self.mission.fly.phase == "land"):
            return int(mav.MAV_LANDED_STATE_LANDING)
        return int(mav.MAV_LANDED_STATE_IN_AIR)
