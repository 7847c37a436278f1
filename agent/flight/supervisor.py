"""The supervisor of one vehicle: arming, flight modes, engage and land through the vehicle's
:mod:`flavour <agent.flight.flavours>`, and the vehicle monitor (is it still ours?).

* Arm and mode commands are confirmed by COMMAND_ACK *and* by the vehicle's HEARTBEAT
  (base_mode bit 128, custom_mode); commands are retried on a missing ACK.
* Engage: the flavour's steps (ArduPilot: GUID_OPTIONS bit 3, GUIDED_NOGPS; PX4: set-points
  streamed ``prestream_s``, OFFBOARD), then arm. Land: the flavour's landing mode.
* Monitoring (:class:`~agent.flight.monitor.VehicleMonitor`, fed from HEARTBEAT, SYS_STATUS,
  BATTERY_STATUS and EXTENDED_SYS_STATE; checked by :meth:`Supervisor.watch`, which the
  set-point stream calls at ≥ 10 Hz): once engaged, the vehicle leaves our control on link
  loss, a mode change (a pilot's switch, the autopilot's failsafe, a fence breach's action),
  a disarm, the autopilot's failsafe state, its landed state, or a critical battery. Then
  streaming stops at once and no mode is ever commanded again (a pilot always wins;
  ``released`` holds the verdict), except LAND on a critical battery while the vehicle is
  still in our mode.

Phases (``phase``): idle | flying | failsafe_hold | released | landing | landed; every change
is passed to ``on_phase`` (the flying agent says them), whose failures are logged.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

from agent.flight.driver_types import FlightError
from agent.flight.flavours import Autopilot, flavour
from agent.flight.link import VehicleLink
from agent.flight.monitor import MonitorConfig, VehicleMonitor, Verdict
from agent.flight.params import ParamClient
from agent.wire.mavlink import FORCE_DISARM_MAGIC, mavlink

_log = logging.getLogger(f"viscover.{__name__}")

_STATUS = ("SYS_STATUS", "BATTERY_STATUS", "EXTENDED_SYS_STATE")


class Supervisor:
    """Modes, arming, engage/land and the monitor of the vehicle behind ``link``."""

    def __init__(self, link: VehicleLink, params: ParamClient) -> None:
        self.link = link
        self.params = params
        self.cfg = link.cfg
        self.clock = link.clock
        self.on_phase: Callable[[str], None] | None = None
        self._phase = "idle"
        self.monitor: VehicleMonitor | None = None  #: from the vehicle's first HEARTBEAT
        self.released: Verdict | None = None  #: why the vehicle left our control
        self.streaming = False  #: set-points may go out
        self._mon_lock = threading.Lock()
        self._threads: list[threading.Thread] = []
        self._unsubs = [link.subscribe("HEARTBEAT", self._on_heartbeat),
                        link.subscribe(_STATUS, self._on_status)]

    def close(self) -> None:
        """Stop listening; join a landing command still in flight."""
        for u in self._unsubs:
            u()
        for th in self._threads:
            th.join(5.0)
        self._threads.clear()

    @property
    def flavour(self) -> Autopilot:
        """The flavour we fly the vehicle as (``cfg.autopilot``)."""
        return flavour(self.cfg.autopilot)

    # -- phase --------------------------------------------------------------------------------
    @property
    def phase(self) -> str:
        """idle | flying | failsafe_hold | released | landing | landed."""
        return self._phase

    @phase.setter
    def phase(self, new: str) -> None:
        old, self._phase = self._phase, new
        if new != old and self.on_phase is not None:
            try:
                self.on_phase(new)
            except Exception:
                _log.exception("on_phase callback failed")

    def note(self, level: int, msg: str, *args: object) -> None:
        """A failsafe line: in the log at ``level``, or at DEBUG when an ``on_phase`` listener
        says the phase itself (one line per event, never two)."""
        _log.log(logging.DEBUG if self.on_phase is not None else level, msg, *args)

    # -- monitor inputs ---------------------------------------------------------------------
    def _monitor(self) -> VehicleMonitor:
        """The vehicle monitor (created on the target's first HEARTBEAT; under _mon_lock)."""
        if self.monitor is None:
            fl = self.flavour
            self.monitor = VehicleMonitor(
                fl, fl.control_modes(), self.link.target_system, self.cfg.target_component,
                self.link.own_system, self.cfg.source_component,
                MonitorConfig(heartbeat_timeout_s=self.cfg.heartbeat_timeout_s,
                              battery_critical_pct=self.cfg.battery_critical_pct))
        return self.monitor

    def _on_heartbeat(self, msg: Any) -> None:
        if msg.type in (mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_ONBOARD_CONTROLLER) \
                or msg.autopilot == mavlink.MAV_AUTOPILOT_INVALID:
            return
        with self._mon_lock:
            self._monitor().on_heartbeat(
                self.clock.now(), int(msg.get_srcSystem()), int(msg.get_srcComponent()),
                int(msg.base_mode), int(msg.custom_mode), int(msg.system_status),
                int(msg.autopilot))

    def _on_status(self, msg: Any) -> None:
        """SYS_STATUS / BATTERY_STATUS / EXTENDED_SYS_STATE to the monitor (after a HEARTBEAT)."""
        kind = msg.get_type()
        t, sysid, compid = self.clock.now(), int(msg.get_srcSystem()), int(msg.get_srcComponent())
        with self._mon_lock:
            mon = self.monitor
            if mon is None:
                return
            if kind == "SYS_STATUS":
                mon.on_sys_status(t, float(msg.battery_remaining),
                                  float(msg.voltage_battery) / 1000.0, sysid, compid)
            elif kind == "BATTERY_STATUS":
                mon.on_battery_status(t, float(msg.battery_remaining), int(msg.charge_state),
                                      -1.0, sysid, compid)
            else:
                mon.on_extended_sys_state(t, int(msg.landed_state), sysid, compid)

    # -- monitoring -----------------------------------------------------------------------------
    def watch(self) -> Verdict | None:
        """Check the monitor; on the first verdict that the vehicle left our control while we
        fly it, stop commanding (:meth:`_release`). Returns that verdict (None while ours)."""
        if self.released is not None:
            return self.released
        if self.phase not in ("flying", "failsafe_hold"):
            return None
        with self._mon_lock:
            mon = self.monitor
            verdict = None if mon is None else mon.check(self.clock.now())
        if verdict is None or verdict.in_control or verdict.code == "idle":
            return None
        self._release(verdict)
        return verdict

    def _release(self, verdict: Verdict) -> None:
        """The vehicle is no longer ours: no more set-points, never a mode command (a pilot
        or the autopilot's failsafe has it), except LAND on a critical battery in our mode."""
        self.streaming = False
        self.released = verdict
        self.phase = "released"
        _log.warning("vehicle left our control: %s", verdict.reason)
        if verdict.code == "battery_critical" and self.mode_is_ours():
            self.land_async()

    def mode_is_ours(self) -> bool:
        """The vehicle's last HEARTBEAT shows it armed in the mode we fly it in."""
        v = self.link.vehicle
        return v.armed and self.flavour.in_control_mode(v.custom_mode)

    def may_command(self) -> bool:
        """Whether we may still send mode commands: never after the vehicle left our control,
        except to land it on a critical battery while it is still in our mode."""
        r = self.released
        return r is None or (r.code == "battery_critical" and self.mode_is_ours())

    # -- commands (EngageSteps) -----------------------------------------------------------------
    def set_mode(self, main: int, sub: int = 0) -> None:
        """MAV_CMD_DO_SET_MODE, confirmed by COMMAND_ACK and by HEARTBEAT.custom_mode."""
        params, expect = self.flavour.set_mode_params(main, sub)
        res = self.link.command(mavlink.MAV_CMD_DO_SET_MODE, *params)
        if res != mavlink.MAV_RESULT_ACCEPTED:
            raise FlightError(f"mode {main}/{sub} refused (MAV_RESULT {res})")
        fl = self.flavour
        self.link.wait_heartbeat_showing(
            lambda v: fl.mode_key(v.custom_mode) == fl.mode_key(expect), f"custom_mode {expect}")

    def arm(self, armed: bool = True, force: bool = False) -> None:
        """MAV_CMD_COMPONENT_ARM_DISARM, confirmed by COMMAND_ACK and HEARTBEAT bit 128."""
        res = self.link.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0 if armed else 0.0,
                                float(FORCE_DISARM_MAGIC) if force else 0.0)
        if res != mavlink.MAV_RESULT_ACCEPTED:
            raise FlightError(f"{'arming' if armed else 'disarming'} refused (MAV_RESULT {res})")
        self.link.wait_heartbeat_showing(lambda v: v.armed == armed,
                                         "armed" if armed else "disarmed")

    def ensure_param_bits(self, name: str, bits: int) -> None:
        """Make integer parameter ``name`` include ``bits`` and confirm it."""
        self.params.ensure_bits(name, bits)

    def wait_streaming(self, seconds: float) -> None:
        """Let the set-point stream run for ``seconds`` [s sim]."""
        t0 = self.clock.now()
        self.link.wait(lambda: self.clock.now() - t0 >= seconds, seconds + 1.0)

    @property
    def set_guid_options(self) -> bool:
        """Whether we may set ArduCopter's GUID_OPTIONS bit 3 ourselves."""
        return self.cfg.set_guid_options

    @property
    def prestream_s(self) -> float:
        """Set-points stream this long before a stream-gated mode (PX4 OFFBOARD) [s sim]."""
        return self.cfg.prestream_s

    # -- engage / land -------------------------------------------------------------------------
    def engage(self, prepare: Callable[[], None], after_arm: Callable[[], None]) -> None:
        """Handshake: HEARTBEAT, ``prepare()`` (the stream's hold), streaming on, the
        flavour's steps, arm, ``after_arm()``; the monitor engaged. Raises
        :class:`FlightError` naming the failed step, with the stream stopped."""
        self.link.wait_heartbeat()
        self.released = None
        prepare()
        self.streaming = True
        self.phase = "flying"
        try:
            self.flavour.engage(self)
            self.arm(True)
        except BaseException:
            self.streaming = False  # a failed handshake leaves no set-point stream running
            self.phase = "idle"
            raise
        after_arm()
        with self._mon_lock:
            self._monitor().engage(self.clock.now())

    def land(self, wait: bool = True, timeout_s: float = 30.0) -> bool:
        """Switch to the flight controller's landing mode; wait (sim s) until it reports
        disarmed. Returns True once disarmed (or if it never armed). After the vehicle left
        our control nothing is commanded (:meth:`may_command`): this only waits for the
        disarm the pilot or the autopilot brings about."""
        v = self.link.vehicle
        if not v.armed:
            self.phase = "landed"
            return True
        if not self.may_command():
            _log.warning("not commanding LAND: the vehicle is not ours (%s)",
                         self.released.reason if self.released else "")
            return not v.armed
        self.streaming = False
        self.phase = "landing"
        try:
            self.flavour.land(self)
        except FlightError as e:
            _log.error("land: %s", e)
            return False
        if not wait:
            return True
        ok = self.link.wait(lambda: not v.armed, timeout_s)
        if ok:
            self.phase = "landed"
        return ok

    def land_async(self) -> None:
        """Command LAND on a thread of its own (from the stream or the monitor)."""
        th = threading.Thread(target=self.land, kwargs={"wait": False}, name="mav-land",
                              daemon=True)
        self._threads.append(th)
        th.start()
