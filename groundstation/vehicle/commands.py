"""COMMAND_LONG / COMMAND_INT of the simulated autopilot: read, checked, answered.

Each command addressed to the vehicle (:func:`~groundstation.vehicle.inbound.addressed_to`)
gets exactly one COMMAND_ACK, sent to its sender's system and component (GCS_Common.cpp;
PX4 ``MavlinkReceiver::acknowledge``): MAV_RESULT_UNSUPPORTED for a command the vehicle does
not know or an ARM_DISARM param1 it does not read (:func:`~.inbound.arm_request`),
MAV_RESULT_DENIED for a parameter that is not a number the command can take (NaN, ±inf,
out of its integer range), otherwise the result of the command. MESSAGE_INTERVAL and
requested messages follow their ACK. Handlers get param1..param7 (COMMAND_INT's x, y, z as
param5..7; its frame in ``cmd_frame``, its sender in ``cmd_src``). Camera, gimbal and fence
commands: :mod:`groundstation.vehicle.devices`. MAV_CMD_NAV_TAKEOFF and MAV_CMD_GET_HOME_POSITION:
:mod:`groundstation.vehicle.modes`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from agent.wire.mavlink import mavlink as mav
from groundstation.vehicle import telemetry as tm
from groundstation.vehicle.inbound import INT32, MSG_ID, UINT8, UINT32, as_int

if TYPE_CHECKING:
    from groundstation.vehicle.flavours.base import SimFlavour

Params = list[float]


class Commands:
    """The command handlers of :class:`groundstation.vehicle.autopilot.Autopilot` (mixin)."""

    flavour: SimFlavour
    streams: tm.MessageStreams
    _requested: list[int]
    _interval_replies: list[int]
    cmd_frame: int | None  #: COMMAND_INT's frame while its handler runs (None: COMMAND_LONG)
    cmd_src: tuple[int, int]  #: the sender (system, component) while its handler runs

    @property
    def mav(self) -> mav.MAVLink:
        """The vehicle's MAVLink encoder (overridden by the autopilot)."""
        raise NotImplementedError

    def _arm(self, arm: bool, force: bool, t: float) -> int:
        """Arm or disarm; the MAV_RESULT (overridden by the autopilot)."""
        raise NotImplementedError

    def _set_mode(self, base: int, custom: int, t: float, sub: int = 0) -> int:
        """DO_SET_MODE / SET_MODE; the MAV_RESULT (overridden by the autopilot)."""
        raise NotImplementedError

    def _switch_to(self, kind: str, t: float) -> int:
        """Enter this flavour's LAND or RTL; the MAV_RESULT (overridden by the autopilot)."""
        raise NotImplementedError

    def _cmd_takeoff(self, p: Params, t: float, frame: int | None) -> int:
        """MAV_CMD_NAV_TAKEOFF; the MAV_RESULT (overridden by the autopilot)."""
        raise NotImplementedError

    def device_commands(self) -> dict[int, Callable[[Params, float], int]]:
        """Camera, gimbal and fence commands (overridden by the autopilot's devices)."""
        return {}

    def _command_table(self) -> dict[int, Callable[[Params, float], int]]:
        return self.device_commands() | {
            mav.MAV_CMD_COMPONENT_ARM_DISARM: self._cmd_arm_disarm,
            mav.MAV_CMD_DO_SET_MODE: self._cmd_set_mode,
            mav.MAV_CMD_NAV_LAND: lambda _p, t: self._switch_to("land", t),
            mav.MAV_CMD_NAV_RETURN_TO_LAUNCH: lambda _p, t: self._switch_to("rtl", t),
            mav.MAV_CMD_SET_MESSAGE_INTERVAL: self._cmd_set_message_interval,
            mav.MAV_CMD_GET_MESSAGE_INTERVAL: self._cmd_get_message_interval,
            mav.MAV_CMD_REQUEST_MESSAGE: self._cmd_request_message,
            mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
                lambda _p, _t: self._request(tm.AUTOPILOT_VERSION),
            mav.MAV_CMD_NAV_TAKEOFF: lambda p, t: self._cmd_takeoff(p, t, self.cmd_frame),
            mav.MAV_CMD_GET_HOME_POSITION: lambda _p, _t: self._request(tm.HOME_POSITION),
        }

    def _on_command(self, m: Any, t: float) -> None:
        """COMMAND_LONG / COMMAND_INT: one COMMAND_ACK to its sender, then any reply."""
        cmd = int(m.command)
        self.cmd_src = (m.get_srcSystem(), m.get_srcComponent())
        handler = self._command_table().get(cmd)
        p = [float(getattr(m, f"param{k}")) for k in range(1, 5)]
        if m.get_type() == "COMMAND_INT":  # x, y (int32, degE7 for global frames), z
            p += [float(m.x), float(m.y), float(m.z)]
            self.cmd_frame = int(m.frame)
        else:
            p += [float(m.param5), float(m.param6), float(m.param7)]
            self.cmd_frame = None
        result = mav.MAV_RESULT_UNSUPPORTED if handler is None else handler(p, t)
        self.mav.command_ack_send(cmd, result, 0, 0, m.get_srcSystem(), m.get_srcComponent())
        for msgid in self._interval_replies:
            self.mav.message_interval_send(msgid, self.streams.interval_us(msgid))
        self._interval_replies.clear()

    def _cmd_arm_disarm(self, p: Params, t: float) -> int:
        request = self.flavour.arm_request(p[0], p[1])
        if request is None:
            return int(mav.MAV_RESULT_UNSUPPORTED)
        return self._arm(*request, t)

    def _cmd_set_mode(self, p: Params, t: float) -> int:
        base, custom, sub = as_int(p[0], UINT8), as_int(p[1], UINT32), as_int(p[2], UINT8)
        if base is None or custom is None:
            return int(mav.MAV_RESULT_DENIED)
        if sub is None:  # only PX4's AUTO modes read param3; elsewhere it is "not given"
            if self.flavour.reads_sub_mode(custom):
                return int(mav.MAV_RESULT_DENIED)
            sub = 0
        return self._set_mode(base, custom, t, sub)

    def _cmd_set_message_interval(self, p: Params, t: float) -> int:
        msgid, interval = as_int(p[0], MSG_ID), as_int(p[1], INT32)
        if msgid is None or interval is None:
            return int(mav.MAV_RESULT_DENIED)
        ok = self.streams.set_interval(msgid, float(interval), t)
        return int(mav.MAV_RESULT_ACCEPTED if ok else mav.MAV_RESULT_UNSUPPORTED)

    def _cmd_get_message_interval(self, p: Params, _t: float) -> int:
        msgid = as_int(p[0], (0, 0xFFFF))  # MESSAGE_INTERVAL.message_id is a uint16
        if msgid is None:
            return int(mav.MAV_RESULT_DENIED)
        self._interval_replies.append(msgid)
        return int(mav.MAV_RESULT_ACCEPTED)

    def _cmd_request_message(self, p: Params, _t: float) -> int:
        msgid = as_int(p[0], MSG_ID)
        return mav.MAV_RESULT_DENIED if msgid is None else self._request(msgid)

    def _request(self, msgid: int) -> int:
        if not tm.available(self, msgid):
            return int(mav.MAV_RESULT_UNSUPPORTED)
        self._requested.append(msgid)
        return int(mav.MAV_RESULT_ACCEPTED)
