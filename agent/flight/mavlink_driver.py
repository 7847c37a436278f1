"""MAVLink driver of one drone (thesis section 6.1): mocap poses in, attitude set-points out.

(Over 400 lines, not split: the handshake, the parameter protocol, the receive loop, the
vehicle monitor's inputs and the set-point stream share one link, one lock and one vehicle
state; a fifth of the file is this docstring, the MAVLink contract. Its settings and data
types are in :mod:`agent.flight.driver_types`, the pure rules it applies in
:mod:`~agent.flight.monitor` and :mod:`~agent.flight.hover`.)

Speaks MAVLink 2 with pymavlink to any connection string (``udpout:host:port``,
``udpin:host:port``, ``/dev/ttyUSB0``...), as a companion computer:

* HEARTBEAT every second as MAV_TYPE_ONBOARD_CONTROLLER (autopilot INVALID, component 191).
* Arm and mode handshake, each confirmed by COMMAND_ACK *and* by the vehicle's HEARTBEAT
  (base_mode bit 128, custom_mode); commands are retried on a missing ACK.
* SET_ATTITUDE_TARGET streamed at ``rate_hz`` (50 Hz default): q = R_NED←FRD (unit, checked),
  thrust 0..1; type_mask 7 (attitude + thrust) or 3 with the body yaw rate as feed-forward
  (``yaw_rate_ff``; PX4 uses it, ArduCopter takes body rates all-or-none, so keep 7 there).
  The stream is pose-driven: a set-point goes out as soon as a new pose arrives and at least
  ``(1 − slack)`` of a period has passed, or at the period plus ``slack`` without a new pose,
  so the latency from pose to set-point is the controller's compute time.
* Mocap is forwarded to the flight controller for its EKF as VISION_POSITION_ESTIMATE or
  ODOMETRY (``forward``), at most ``forward_hz``; covariances are unknown, sent as NaN in
  their first element (MAVLink's convention; PX4 then uses its EKF2_EV*_NOISE parameters).
* Parameters (:meth:`MavlinkDriver.read_params`): PARAM_REQUEST_READ by name, PARAM_VALUE
  decoded by param_type (PX4 sends integers byte-wise, ArduPilot as floats).
* COMMAND_ACK counts only when it comes from the vehicle and is addressed to us (target
  system / component ours, or 0 as in MAVLink 1): a ground station's ACK is not ours.
* Hover thrust: the controller's thrust model is seeded from the autopilot's own parameter
  and re-estimated in flight (:class:`agent.flight.hover.HoverThrustEstimator`), fed with the
  acceleration differenced from the mocap velocity while airborne; every failsafe reads the
  controller's current model.

Flavours:

* ``ardupilot``: mode GUIDED_NOGPS (20). ArduCopter reads SET_ATTITUDE_TARGET.thrust as a
  climb-rate command (0.5 = hold) unless GUID_OPTIONS bit 3 (value 8) is set, in which case it
  is real normalised thrust. The driver reads GUID_OPTIONS, ORs in 8, writes it and confirms
  it (``set_guid_options``); with that off you must set it yourself. LAND = mode 9.
* ``px4``: mode OFFBOARD (main mode 6); set-points stream for ``px4_prestream_s`` before the
  switch, as PX4 requires. LAND = AUTO (4) / LAND (6).

Monitoring (:class:`agent.flight.monitor.VehicleMonitor`, fed from the receive loop and
checked by the stream loop at every iteration, ≥ 10 Hz): once engaged, the vehicle leaves our
control on link loss (no HEARTBEAT for ``heartbeat_timeout_s``), a mode change (a pilot's
switch or the autopilot's failsafe), a disarm, the autopilot's failsafe state, its landed
state, or a critical battery. Then the driver stops streaming at once and never commands a
mode again (a pilot always wins; ``released`` holds the verdict), with one exception: a
critical battery while the vehicle is still in our mode is landed with the autopilot's LAND.

Failsafes (all observable from the vehicle side):

* mocap older than ``mocap_stale_s`` → level attitude at hover thrust (``failsafe_hold``);
  still stale after ``failsafe_hold_s`` → the flight controller's LAND mode (``landing``),
  where it descends on its own sensors and disarms on touchdown. The age is
  :class:`~agent.flight.monitor.MocapAge`'s, on the ground station's own stamps: a pose
  provider that hears the station's clock carries one as ``mocap_age``
  (:class:`~agent.flight.vehicle_pose.ZenohMocapFeed` does); for any other provider the
  driver's own clock stands for the station's (age = ``clock.now()`` − the pose's stamp).
  One line per failsafe and one per recovery: through ``on_phase`` when a listener says the
  phases (the flying agent), else in the log;
* a set-point with a NaN/inf or a non-unit quaternion is never sent: it is replaced by the
  level hover set-point and counted (``stats.blocked``);
* positions outside the mission space are never commanded (the controller clips holds and
  brakes velocities at the walls, :mod:`agent.flight.controllers`);
* :func:`land_on_signals`: SIGINT/SIGTERM land the drone before the process exits.

Fault injection (``faults``, an :class:`agent.net.faults.FaultInjector`): set-points of kind
``setpoint`` are dropped as the injector decides (delays are not applied to set-points);
mocap drops and delays come from the transport's own injector on the pose subscription.

Times are simulation seconds of the mission clock (:class:`agent.clock.Clock`); with a scaled
clock the whole driver runs faster than real time.
"""

from __future__ import annotations

import contextlib
import logging
import math
import signal
import threading
import time
from collections.abc import Callable, Iterator
from types import FrameType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agent.clock import Clock, WallClock
from agent.flight.attitude import AttitudeCommand, level_attitude
from agent.flight.controllers import FlightController, FlightState
from agent.flight.driver_types import (
    DriverConfig,
    DriverStats,
    FlightError,
    PoseProvider,
    PoseSample,
    VehicleState,
    decode_param_value,
    split_baud,
)
from agent.flight.frames import (
    enu_to_ned,
    euler_from_quat,
    quat_enu_flu_to_ned_frd,
    quat_is_unit,
    quat_to_matrix,
    yaw_enu_to_ned,
    yaw_from_quat,
)
from agent.flight.hover import AccelFromVelocity
from agent.flight.monitor import MocapAge, MonitorConfig, VehicleMonitor, Verdict
from agent.net.faults import FaultInjector
from agent.wire.mavlink import (
    ARDUPILOT_GUIDED_NOGPS,
    ARDUPILOT_LAND,
    GUID_OPTIONS_REAL_THRUST,
    PX4_AUTO_LAND,
    PX4_OFFBOARD,
    mavlink,
    mavutil,
    px4_custom_mode,
)

_log = logging.getLogger(f"viscover.{__name__}")
Array = NDArray[np.float64]

class MavlinkDriver:
    """One vehicle. ``pose`` supplies mocap poses; ``controller`` turns them into set-points.

    Lifecycle: ``start()`` (threads, heartbeats, stream), ``engage()`` (handshake, raises
    :class:`FlightError`), fly by driving ``controller`` (velocity or hold), ``land()``,
    ``close()``. ``notify_pose()`` wakes the stream when a pose arrives.
    """

    def __init__(self, connection: str, pose: PoseProvider, controller: FlightController,
                 config: DriverConfig | None = None, clock: Clock | None = None,
                 source_system: int | None = None, faults: FaultInjector | None = None) -> None:
        self.cfg = config or DriverConfig()
        self.faults = faults
        self.clock = clock or WallClock()
        self.pose = pose
        self.controller = controller
        self.target_system = self.cfg.target_system
        sysid = (self.target_system or 1) if source_system is None else source_system
        self._fixed_source = source_system is not None
        device, baud = split_baud(connection)
        try:
            self.conn = mavutil.mavlink_connection(
                device, baud=baud, source_system=sysid,
                source_component=self.cfg.source_component, autoreconnect=True,
            )
        except (OSError, ValueError) as e:
            raise FlightError(f"cannot open MAVLink connection {connection!r}: {e}") from None
        self.vehicle = VehicleState()
        self.stats = DriverStats()
        self.on_phase: Callable[[str], None] | None = None  # called on every phase change
        self._phase = "idle"
        self.monitor: VehicleMonitor | None = None  # from the vehicle's first HEARTBEAT
        self.released: Verdict | None = None  # why the vehicle left our control
        self._accel = AccelFromVelocity()
        self._z_ground = math.inf
        self._send_lock = threading.Lock()
        self._cond = threading.Condition()
        self._acks: dict[int, int] = {}
        self._pose_seq = 0
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._failsafe_since: float | None = None
        provided = getattr(pose, "mocap_age", None)
        self._own_age = not isinstance(provided, MocapAge)  # then fed from self.clock
        self.mocap_age: MocapAge = provided if isinstance(provided, MocapAge) else MocapAge()
        self.failsafe_reason = ""  #: why the last mocap failsafe started (one line)
        self.failsafe_s = 0.0  #: how long the last mocap failsafe lasted [s sim]
        self._last_fwd_t = -math.inf
        self._last_pose_t = -math.inf
        self._last_yaw_ned = 0.0
        self.streaming = False

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

    def _note(self, level: int, msg: str, *args: object) -> None:
        """A failsafe line: in the log at ``level``, or at DEBUG when an ``on_phase`` listener
        says the phase itself (one line per event, never two)."""
        _log.log(logging.DEBUG if self.on_phase is not None else level, msg, *args)

    # -- lifecycle ------------------------------------------------------------------------
    def start(self) -> MavlinkDriver:
        """Start the receive and stream threads (heartbeats go out from now on)."""
        for name, fn in (("mav-rx", self._rx_loop), ("mav-stream", self._stream_loop)):
            th = threading.Thread(target=fn, name=name, daemon=True)
            th.start()
            self._threads.append(th)
        return self

    def close(self) -> None:
        """Stop and join the threads, close the connection. Does not land (see :meth:`land`)."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        for th in self._threads:
            th.join(5.0)
        self._threads.clear()
        with contextlib.suppress(OSError):
            self.conn.close()

    def __enter__(self) -> MavlinkDriver:
        return self.start()

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # -- receive ----------------------------------------------------------------------------
    def _rx_loop(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.conn.recv_match(blocking=True, timeout=0.05)
            except (OSError, ValueError) as e:
                _log.debug("recv failed: %s", e)
                self._stop.wait(0.05)
                continue
            if msg is None:
                continue
            self._on_message(msg)

    def _on_message(self, msg: Any) -> None:
        """Update the vehicle state from one message of the target system."""
        kind = msg.get_type()
        if kind == "HEARTBEAT" and self.target_system == 0 \
                and msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID \
                and msg.type not in (mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_ONBOARD_CONTROLLER):
            self.target_system = int(msg.get_srcSystem())  # adopt the first vehicle
            if not self._fixed_source:
                self.conn.mav.srcSystem = self.target_system  # a companion shares its sysid
        if msg.get_srcSystem() != self.target_system:
            return
        v = self.vehicle
        if kind == "HEARTBEAT":
            if msg.type in (mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_ONBOARD_CONTROLLER) \
                    or msg.autopilot == mavlink.MAV_AUTOPILOT_INVALID:
                return  # a ground station, a companion or a camera of the same system
            with self._cond:
                v.heartbeat_wall = time.monotonic()
                v.armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
                v.custom_mode = int(msg.custom_mode)
                v.autopilot = int(msg.autopilot)
                self._monitor().on_heartbeat(
                    self.clock.now(), int(msg.get_srcSystem()), int(msg.get_srcComponent()),
                    int(msg.base_mode), int(msg.custom_mode), int(msg.system_status),
                    int(msg.autopilot))
                self._cond.notify_all()
        elif kind == "COMMAND_ACK":
            if not self._ack_is_ours(msg):
                return
            with self._cond:
                self._acks[int(msg.command)] = int(msg.result)
                self._cond.notify_all()
        elif kind == "PARAM_VALUE":
            bytewise = v.autopilot == mavlink.MAV_AUTOPILOT_PX4 or (
                v.autopilot < 0 and self.cfg.autopilot == "px4")
            name = str(msg.param_id)
            with self._cond:
                v.params[name] = decode_param_value(float(msg.param_value),
                                                    int(msg.param_type), bytewise)
                v.param_types[name] = int(msg.param_type)
                self._cond.notify_all()
        elif kind in ("SYS_STATUS", "BATTERY_STATUS", "EXTENDED_SYS_STATE"):
            self._monitor_status(kind, msg)
        elif kind == "ATTITUDE":
            v.attitude = (float(msg.roll), float(msg.pitch), float(msg.yaw))
        elif kind == "LOCAL_POSITION_NED":
            v.position_ned = (float(msg.x), float(msg.y), float(msg.z),
                              float(msg.vx), float(msg.vy), float(msg.vz))

    def _ack_is_ours(self, msg: Any) -> bool:
        """A COMMAND_ACK addressed to this companion (target 0 = unset, MAVLink 1)."""
        ts, tc = int(getattr(msg, "target_system", 0)), int(getattr(msg, "target_component", 0))
        return ts in (0, int(self.conn.mav.srcSystem)) and tc in (0, self.cfg.source_component)

    def _monitor(self) -> VehicleMonitor:
        """The vehicle monitor (created on the target's first HEARTBEAT; call under _cond)."""
        if self.monitor is None:
            expected = [ARDUPILOT_GUIDED_NOGPS] if self.cfg.autopilot == "ardupilot" else \
                [px4_custom_mode(*PX4_OFFBOARD)]
            self.monitor = VehicleMonitor(
                self.cfg.autopilot, expected, self.target_system, self.cfg.target_component,
                int(self.conn.mav.srcSystem), self.cfg.source_component,
                MonitorConfig(heartbeat_timeout_s=self.cfg.heartbeat_timeout_s,
                              battery_critical_pct=self.cfg.battery_critical_pct))
        return self.monitor

    def _monitor_status(self, kind: str, msg: Any) -> None:
        """SYS_STATUS / BATTERY_STATUS / EXTENDED_SYS_STATE to the monitor (after a HEARTBEAT)."""
        t, sysid, compid = self.clock.now(), int(msg.get_srcSystem()), int(msg.get_srcComponent())
        with self._cond:
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

    # -- monitoring -------------------------------------------------------------------------
    def watch(self) -> Verdict | None:
        """Check the monitor; on the first verdict that the vehicle left our control while we
        fly it, stop commanding (:meth:`_release`). Returns that verdict (None while ours)."""
        if self.released is not None:
            return self.released
        if self.phase not in ("flying", "failsafe_hold"):
            return None
        with self._cond:
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
        if verdict.code == "battery_critical" and self._mode_is_ours():
            th = threading.Thread(target=self.land, kwargs={"wait": False}, name="mav-land",
                                  daemon=True)
            self._threads.append(th)
            th.start()

    def _mode_is_ours(self) -> bool:
        """The vehicle's last HEARTBEAT shows it armed in the mode we fly it in."""
        mode = self.vehicle.custom_mode
        if self.cfg.autopilot == "px4":
            return self.vehicle.armed and mode & 0xFFFF0000 == px4_custom_mode(*PX4_OFFBOARD)
        return self.vehicle.armed and mode == ARDUPILOT_GUIDED_NOGPS

    def may_command(self) -> bool:
        """Whether we may still send mode commands: never after the vehicle left our control,
        except to land it on a critical battery while it is still in our mode."""
        r = self.released
        return r is None or (r.code == "battery_critical" and self._mode_is_ours())

    # -- send -------------------------------------------------------------------------------
    def _ms(self) -> int:
        return int(max(self.clock.now(), 0.0) * 1000.0) & 0xFFFFFFFF

    def send_heartbeat(self) -> None:
        """HEARTBEAT as MAV_TYPE_ONBOARD_CONTROLLER, autopilot INVALID."""
        with self._send_lock:
            self.conn.mav.heartbeat_send(mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
                                         mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                                         mavlink.MAV_STATE_ACTIVE)

    def _command(self, command: int, *params: float) -> int:
        """COMMAND_LONG with retries until a COMMAND_ACK; returns its result."""
        p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        for attempt in range(self.cfg.retries):
            with self._cond:
                self._acks.pop(command, None)
            with self._send_lock:
                self.conn.mav.command_long_send(self.target_system, self.cfg.target_component,
                                                command, attempt, *p)
            if self._wait(lambda: command in self._acks, self.cfg.ack_timeout_s):
                return self._acks[command]
        raise FlightError(f"no COMMAND_ACK for command {command} after {self.cfg.retries} tries")

    def _wait(self, pred: Callable[[], bool], timeout_sim: float) -> bool:
        """Wait until pred() (checked under the condition), at most timeout_sim sim seconds."""
        deadline = self.clock.now() + timeout_sim
        with self._cond:
            while not pred():
                left = deadline - self.clock.now()
                if left <= 0 or self._stop.is_set():
                    return pred()
                self._cond.wait(min(0.05, self.clock.wall(left)))
        return True

    # -- handshake ----------------------------------------------------------------------------
    def wait_heartbeat(self) -> None:
        """Wait for the vehicle's HEARTBEAT; FlightError after ``heartbeat_timeout_s``."""
        self.send_heartbeat()
        if not self._wait(lambda: self.vehicle.heartbeat_wall > 0, self.cfg.heartbeat_timeout_s):
            who = f"system {self.target_system}" if self.target_system else "any vehicle"
            raise FlightError(f"no HEARTBEAT from {who} within "
                              f"{self.cfg.heartbeat_timeout_s:g} s")

    def _wait_hb(self, pred: Callable[[VehicleState], bool], what: str) -> None:
        since = time.monotonic()
        ok = self._wait(lambda: self.vehicle.heartbeat_wall > since and pred(self.vehicle),
                        self.cfg.heartbeat_timeout_s)
        if not ok:
            raise FlightError(f"vehicle HEARTBEAT never showed {what}")

    def set_mode(self, custom: int, sub: int = 0) -> None:
        """MAV_CMD_DO_SET_MODE, confirmed by COMMAND_ACK and by HEARTBEAT.custom_mode."""
        if self.cfg.autopilot == "px4":
            expect = px4_custom_mode(custom, sub)
            res = self._command(mavlink.MAV_CMD_DO_SET_MODE,
                                mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom, sub)
        else:
            expect = custom
            res = self._command(mavlink.MAV_CMD_DO_SET_MODE,
                                mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom)
        if res != mavlink.MAV_RESULT_ACCEPTED:
            raise FlightError(f"mode {custom}/{sub} refused (MAV_RESULT {res})")
        self._wait_hb(lambda v: v.custom_mode == expect, f"custom_mode {expect}")

    def arm(self, armed: bool = True, force: bool = False) -> None:
        """MAV_CMD_COMPONENT_ARM_DISARM, confirmed by COMMAND_ACK and HEARTBEAT bit 128."""
        res = self._command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0 if armed else 0.0,
                            21196.0 if force else 0.0)
        if res != mavlink.MAV_RESULT_ACCEPTED:
            raise FlightError(f"{'arming' if armed else 'disarming'} refused (MAV_RESULT {res})")
        self._wait_hb(lambda v: v.armed == armed, "armed" if armed else "disarmed")

    def _param(self, name: str, value: float | None = None) -> float:
        """Read (value None) or write a parameter, retried until its PARAM_VALUE comes back."""
        for _ in range(self.cfg.retries):
            with self._cond:
                self.vehicle.params.pop(name, None)
            with self._send_lock:
                if value is None:
                    self.conn.mav.param_request_read_send(
                        self.target_system, self.cfg.target_component, name.encode(), -1)
                else:
                    self.conn.mav.param_set_send(
                        self.target_system, self.cfg.target_component, name.encode(),
                        float(value), mavlink.MAV_PARAM_TYPE_REAL32)
            if self._wait(lambda: name in self.vehicle.params, self.cfg.ack_timeout_s):
                return self.vehicle.params[name]
        raise FlightError(f"no PARAM_VALUE for {name} after {self.cfg.retries} tries")

    def read_params(self, names: list[str], rounds: int | None = None) -> dict[str, float]:
        """Read parameters by name (PARAM_REQUEST_READ, all at once; the missing ones asked
        again up to ``rounds`` times, ``ack_timeout_s`` each). Returns those that answered,
        decoded by their param_type; an autopilot without a parameter never answers."""
        with self._cond:
            for n in names:
                self.vehicle.params.pop(n, None)
        for _ in range(self.cfg.retries if rounds is None else rounds):
            missing = [n for n in names if n not in self.vehicle.params]
            if not missing:
                break
            for n in missing:
                with self._send_lock:
                    self.conn.mav.param_request_read_send(
                        self.target_system, self.cfg.target_component, n.encode(), -1)
            self._wait(self._have_params(missing), self.cfg.ack_timeout_s)
        with self._cond:
            return {n: self.vehicle.params[n] for n in names if n in self.vehicle.params}

    def _have_params(self, names: list[str]) -> Callable[[], bool]:
        """A predicate: every parameter of ``names`` has arrived."""
        return lambda: all(n in self.vehicle.params for n in names)

    def ensure_guid_options(self) -> None:
        """ArduPilot: make GUID_OPTIONS include bit 3 (8) so thrust is thrust, and confirm."""
        value = int(self._param("GUID_OPTIONS")) | GUID_OPTIONS_REAL_THRUST
        if int(self._param("GUID_OPTIONS", value)) != value:
            raise FlightError("GUID_OPTIONS was not set to include bit 3 (real thrust)")

    def engage(self) -> None:
        """Handshake: HEARTBEAT, (ArduPilot) GUID_OPTIONS, mode, arm; streaming from here on.

        ArduPilot: GUIDED_NOGPS then arm. PX4: stream set-points ``px4_prestream_s``, then
        OFFBOARD, then arm. Raises :class:`FlightError` naming the failed step.
        """
        self.wait_heartbeat()
        self.released = None
        self.controller.set_hold()
        pose = self.pose()
        self._z_ground = float(pose.p[2]) if pose is not None else math.inf
        self._accel.reset()
        self.streaming = True
        self.phase = "flying"
        try:
            if self.cfg.autopilot == "ardupilot":
                if self.cfg.set_guid_options:
                    self.ensure_guid_options()
                self.set_mode(ARDUPILOT_GUIDED_NOGPS)
            else:
                t0 = self.clock.now()
                self._wait(lambda: self.clock.now() - t0 >= self.cfg.px4_prestream_s,
                           self.cfg.px4_prestream_s + 1.0)
                self.set_mode(*PX4_OFFBOARD)
            self.arm(True)
        except BaseException:
            self.streaming = False  # a failed handshake leaves no set-point stream running
            self.phase = "idle"
            raise
        self.controller.reset()  # nothing integrated while sitting on the ground
        with self._cond:
            self._monitor().engage(self.clock.now())

    def land(self, wait: bool = True, timeout_s: float = 30.0) -> bool:
        """Switch to the flight controller's LAND mode; wait (sim s) until it reports disarmed.

        Returns True once disarmed (or if it never armed). After the vehicle left our control
        nothing is commanded (the pilot or the autopilot has it; :meth:`may_command`): this
        only waits for the disarm the pilot or the autopilot brings about."""
        if not self.vehicle.armed:
            self.phase = "landed"
            return True
        if not self.may_command():
            _log.warning("not commanding LAND: the vehicle is not ours (%s)",
                         self.released.reason if self.released else "")
            return not self.vehicle.armed
        self.streaming = False
        self.phase = "landing"
        try:
            if self.cfg.autopilot == "px4":
                self.set_mode(*PX4_AUTO_LAND)
            else:
                self.set_mode(ARDUPILOT_LAND)
        except FlightError as e:
            _log.error("land: %s", e)
            return False
        if not wait:
            return True
        ok = self._wait(lambda: not self.vehicle.armed, timeout_s)
        if ok:
            self.phase = "landed"
        return ok

    # -- stream -------------------------------------------------------------------------------
    def notify_pose(self) -> None:
        """A new pose is available: wake the stream (call from the pose's receive thread)."""
        with self._cond:
            self._pose_seq += 1
            self._cond.notify_all()

    def _stream_loop(self) -> None:
        """Pose-driven set-point stream with a deadline (module docstring), plus heartbeats.

        Paced on the local monotonic clock at the simulation clock's scale, so the stream is
        as regular as the host allows even when the (followed) simulation clock stutters.
        """
        last_send = -math.inf
        last_hb = -math.inf
        seen = 0
        while not self._stop.is_set():
            now = time.monotonic()
            period = self.clock.wall(1.0 / self.cfg.rate_hz)
            if now - last_hb >= self.clock.wall(1.0):
                last_hb = now
                self.send_heartbeat()
            try:
                self.watch()
            except Exception:
                _log.exception("vehicle monitor failed")
            due_pose = last_send + period * (1.0 - self.cfg.slack)
            due_late = last_send + period * (1.0 + self.cfg.slack)
            with self._cond:
                fresh = self._pose_seq != seen
                if not (fresh and now >= due_pose) and now < due_late:
                    # Early pose or none yet: sleep until the next pose or the deadline.
                    self._cond.wait(min(max(due_late - now, 1e-4), 0.1))
                    continue
                seen = self._pose_seq
            last_send = time.monotonic()
            try:
                self._step()
            except Exception:
                _log.exception("stream step failed")

    def _step(self) -> None:
        """One stream period: read the pose, run the controller / failsafe, send."""
        pose = self.pose()
        now = self.clock.now()
        if self._own_age:
            self.mocap_age.heard(now)
        age = self.mocap_age.age(None if pose is None else pose.t)
        fresh = pose is not None and age <= self.cfg.mocap_stale_s
        if pose is not None and pose.t > self._last_pose_t:
            self._last_pose_t = pose.t
            self._forward(pose)
        if not self.streaming:
            return
        if fresh and pose is not None:
            if self._failsafe_since is not None:
                self.failsafe_s = max(0.0, now - self._failsafe_since)
                self._failsafe_since = None
                self._note(logging.WARNING, "mocap back after %.2f s: resuming",
                           self.failsafe_s)
                self.phase = "flying"
                self.controller.set_hold()
            yaw = yaw_from_quat(pose.q)
            a = self._accel.update(pose.t, pose.vel)
            airborne = self.vehicle.armed and float(pose.p[2]) > self._z_ground + 0.1
            acc = np.asarray(a, dtype=np.float64) if a is not None and airborne else None
            on_ground = self.vehicle.armed and not airborne
            sp = self.controller.update(FlightState(pose.p, pose.vel, yaw, pose.t, a=acc,
                                                    on_ground=on_ground))
            self._last_yaw_ned = yaw_enu_to_ned(yaw)
            self._send(sp.cmd, sp.yaw_rate_frd, pose.rx_wall)
            return
        # Failsafe: stale or missing mocap.
        if self._failsafe_since is None:
            self._failsafe_since = now
            self.stats.failsafes += 1
            self.failsafe_reason = self._stale_reason(pose is None, age)
            self._note(logging.WARNING, "mocap lost (%s): level hover at hover thrust",
                       self.failsafe_reason)
            self.phase = "failsafe_hold"
        if now - self._failsafe_since < self.cfg.failsafe_hold_s:
            self._send(level_attitude(self._last_yaw_ned, self.controller.model), 0.0, 0.0)
            return
        _log.warning("mocap still stale after %.1f s: landing", self.cfg.failsafe_hold_s)
        self.streaming = False
        if not self.may_command():
            return
        th = threading.Thread(target=self.land, kwargs={"wait": False}, name="mav-land",
                              daemon=True)
        self._threads.append(th)
        th.start()

    def _stale_reason(self, no_pose: bool, age: float) -> str:
        """Why the pose is not fresh, in a few words (ages in s sim, silence in s wall)."""
        if no_pose:
            return "no pose yet"
        if math.isinf(age):
            return f"ground station silent for {self.mocap_age.silent_for():.2f} s"
        return f"newest pose {age:.3f} s old, limit {self.cfg.mocap_stale_s:.3f} s"

    def _send(self, cmd: AttitudeCommand, yaw_rate_frd: float, rx_wall: float) -> None:
        """SET_ATTITUDE_TARGET after the guard: never a NaN/inf, never a non-unit q."""
        q, thrust = np.asarray(cmd.q, dtype=np.float64), float(cmd.thrust)
        ok = (quat_is_unit(q) and math.isfinite(thrust) and 0.0 <= thrust <= 1.0
              and math.isfinite(yaw_rate_frd))
        if not ok:
            self.stats.blocked += 1
            _log.error("blocked a non-finite or invalid set-point (q=%s thrust=%s)", q, thrust)
            fallback = level_attitude(self._last_yaw_ned, self.controller.model)
            q, thrust, yaw_rate_frd = fallback.q, fallback.thrust, 0.0
        mask = 3 if self.cfg.yaw_rate_ff else 7
        if self.faults is not None and self.faults.decide("setpoint", None, "out").dropped:
            self.stats.dropped += 1  # fault injection: this set-point is lost on the link
            return
        with self._send_lock:
            self.conn.mav.set_attitude_target_send(
                self._ms(), self.target_system, self.cfg.target_component, mask,
                [float(a) for a in q], 0.0, 0.0, float(yaw_rate_frd), thrust)
        t = time.monotonic()
        self.stats.sent += 1
        self.stats.send_wall.append(t)
        if rx_wall > 0:
            self.stats.latency.append(t - rx_wall)

    def _forward(self, pose: PoseSample) -> None:
        """Mocap to the flight controller (VISION_POSITION_ESTIMATE or ODOMETRY, NED/FRD)."""
        if self.cfg.forward == "none" or pose.t - self._last_fwd_t < 1.0 / self.cfg.forward_hz:
            return
        p, q = enu_to_ned(pose.p), quat_enu_flu_to_ned_frd(pose.q)
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(pose.vel))):
            return
        self._last_fwd_t = pose.t
        usec = int(max(pose.t, 0.0) * 1e6)
        with self._send_lock:
            if self.cfg.forward == "vision":
                roll, pitch, yaw = euler_from_quat(q)
                cov = [math.nan] + [0.0] * 20  # unknown: NaN first (MAVLink convention)
                self.conn.mav.vision_position_estimate_send(
                    usec, float(p[0]), float(p[1]), float(p[2]), roll, pitch, yaw, cov)
            else:
                v_body = quat_to_matrix(q).T @ enu_to_ned(pose.vel)
                cov = [math.nan] + [0.0] * 20  # unknown: NaN first (MAVLink convention)
                self.conn.mav.odometry_send(
                    usec, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_FRD,
                    float(p[0]), float(p[1]), float(p[2]), [float(a) for a in q],
                    float(v_body[0]), float(v_body[1]), float(v_body[2]),
                    0.0, 0.0, 0.0, cov, cov)  # rates not measured: 0, never NaN
        self.stats.forwarded += 1


class ShutdownRequested(BaseException):
    """Raised in the main thread by SIGINT/SIGTERM inside :func:`land_on_signals`."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


@contextlib.contextmanager
def land_on_signals(driver: MavlinkDriver, timeout_s: float = 30.0,
                    signals: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM)
                    ) -> Iterator[None]:
    """Within the block, SIGINT/SIGTERM raise :class:`ShutdownRequested`; on leaving the block
    (normally, by signal or by error) the drone lands before control returns. Main thread only.
    """

    def handler(signum: int, _frame: FrameType | None) -> None:
        raise ShutdownRequested(signum)

    old = {s: signal.signal(s, handler) for s in signals}
    try:
        yield
    except ShutdownRequested as e:
        _log.warning("%s: landing before exit", e)
    finally:
        for s in signals:  # a second signal during landing is ignored, not fatal
            signal.signal(s, signal.SIG_IGN)
        try:
            driver.land(wait=True, timeout_s=timeout_s)
        finally:
            for s, h in old.items():
                signal.signal(s, h)
