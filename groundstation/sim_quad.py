"""Simulated quadrotors that speak MAVLink 2 over UDP, as SITL vehicles do.

Physics (vectorised over the fleet, NED world, FRD body): translational rigid-body dynamics
m v̇ = −T z_B + m g ẑ − k_drag v with T = T_max · thrust, a first-order response of roll,
pitch and yaw to the commanded attitude (time constant ``tau_att``) and of the thrust
(``tau_thrust``), ground contact at z = 0 (no penetration, no sliding). Stepped at a fixed
``dt`` [s] up to the shared simulation clock, so it runs as fast as the clock asks.

Autopilot (per vehicle, flavour ``ardupilot`` or ``px4``):

* HEARTBEAT at 1 Hz (base_mode bit 128 = armed, custom_mode = the mode), ATTITUDE and
  LOCAL_POSITION_NED at ``telemetry_rate``, COMMAND_ACK for every COMMAND_LONG.
* MAV_CMD_COMPONENT_ARM_DISARM (disarm in flight only with param2 = 21196),
  MAV_CMD_DO_SET_MODE: ArduPilot param2 = custom mode (GUIDED_NOGPS 20, GUIDED 4, LAND 9,
  STABILIZE 0); PX4 param2 = main mode, param3 = sub mode (OFFBOARD 6; AUTO 4 / LAND 6);
  OFFBOARD is refused unless set-points streamed during the last second (≥ 3 of them).
* SET_ATTITUDE_TARGET, type_mask 7 (attitude + thrust) or 3 (plus the body yaw rate as a yaw
  feed-forward); refused (counted) if q is not unit length within 1e-3 or a field is not
  finite. ArduPilot flavour: thrust is real thrust only when GUID_OPTIONS has bit 3 (value 8,
  settable with PARAM_SET); otherwise it is a climb-rate command (0.5 = hold altitude), as
  ArduCopter does.
* No set-point for longer than ``setpoint_timeout`` in the guided/offboard mode: level and
  hold altitude (event ``setpoint_timeout``). LAND: level, descend at ``land_speed``,
  disarm on touchdown (events ``land`` and ``landed``).
* VISION_POSITION_ESTIMATE / ODOMETRY are counted (what a real EKF would fuse).

The fleet is also the motion-capture source of the ground station in simulation:
:meth:`SimFleet.mocap` returns each vehicle's true pose delayed by ``mocap_latency`` with
Gaussian noise (seeded), in mission frames (ENU world, FLU body).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from agent.clock import Clock
from agent.flight.frames import (
    euler_from_quat,
    ned_to_enu,
    quat_from_euler,
    quat_is_unit,
    quat_ned_frd_to_enu_flu,
    quat_normalize,
    wrap_pi,
)
from agent.wire.mavlink import (
    ARDUPILOT_MODES,
    FORCE_DISARM_MAGIC,
    GUID_OPTIONS_REAL_THRUST,
    PX4_MAIN_AUTO,
    PX4_MAIN_MANUAL,
    PX4_MAIN_OFFBOARD,
    PX4_SUB_AUTO_LAND,
    mavutil,
    px4_custom_mode,
)

_log = logging.getLogger(__name__)
Array = NDArray[np.float64]
mav = mavutil.mavlink

@dataclass(frozen=True)
class VehicleParams:
    """Simulated vehicle: mass [kg], hover thrust (normalised; T_max = m g / hover_thrust),
    linear drag [N s/m], attitude / thrust time constants [s], set-point timeout [s],
    landing speed [m/s], climb rate at full stick for ArduPilot's climb-rate thrust [m/s],
    telemetry rate [Hz sim], mocap noise (position [m], angle [rad]) and latency [s]."""

    mass: float = 1.5
    g: float = 9.81
    hover_thrust: float = 0.5
    drag: float = 0.25
    tau_att: float = 0.08
    tau_thrust: float = 0.03
    setpoint_timeout: float = 0.5
    land_speed: float = 0.5
    pilot_speed: float = 2.5
    telemetry_rate: float = 30.0
    mocap_noise_pos: float = 0.0
    mocap_noise_att: float = 0.0
    mocap_latency: float = 0.0
    autopilot: str = "ardupilot"

    def __post_init__(self) -> None:
        if self.autopilot not in ("ardupilot", "px4"):
            raise ValueError(f"autopilot must be 'ardupilot' or 'px4', got {self.autopilot!r}")
        if not (self.mass > 0 and 0 < self.hover_thrust < 1 and self.tau_att > 0):
            raise ValueError("mass > 0, 0 < hover_thrust < 1 and tau_att > 0 are required")

    @property
    def max_thrust(self) -> float:
        """T_max [N] = m g / hover_thrust."""
        return self.mass * self.g / self.hover_thrust


@dataclass
class MocapSample:
    """One mocap observation in mission frames: time [s sim], position [m ENU], velocity
    [m/s ENU], attitude q = R_ENU←FLU (w, x, y, z)."""

    t: float
    p: Array
    v: Array
    q: Array


@dataclass
class VehicleLog:
    """What the vehicle saw (for tests and reports): events (t, name), counters, last
    accepted set-point and the last non-finite or rejected one."""

    events: list[tuple[float, str]] = field(default_factory=list)
    setpoints: int = 0
    rejected_quat: int = 0
    rejected_nonfinite: int = 0
    rejected_mode: int = 0
    vision: int = 0
    odometry: int = 0
    heartbeats_rx: int = 0
    last_thrust: float = math.nan
    last_q: Array = field(default_factory=lambda: np.full(4, np.nan))
    last_type_mask: int = -1
    last_setpoint_wall: float = 0.0
    last_vision_wall: float = 0.0
    setpoint_times: deque[float] = field(default_factory=lambda: deque(maxlen=4096))

    def has(self, name: str) -> bool:
        """Whether event ``name`` happened."""
        return any(n == name for _, n in self.events)


class SimQuad:
    """One vehicle's autopilot logic and MAVLink endpoint (``udpin:host:port``)."""

    def __init__(self, fleet: SimFleet, index: int, name: str, params: VehicleParams,
                 host: str = "127.0.0.1", port: int = 0, sysid: int = 1) -> None:
        self.fleet, self.i, self.name, self.params = fleet, index, name, params
        self.sysid = sysid
        self.conn = mavutil.mavlink_connection(
            f"udpin:{host}:{port}", source_system=sysid, source_component=1
        )
        self.port: int = self.conn.port.getsockname()[1]
        self.armed = False
        self.px4 = params.autopilot == "px4"
        self.mode = px4_custom_mode(PX4_MAIN_MANUAL) if self.px4 else ARDUPILOT_MODES["STABILIZE"]
        self.params_table: dict[str, float] = {"GUID_OPTIONS": 0.0}
        self.log = VehicleLog()
        # Last accepted set-point (NED/FRD) and its simulation time.
        self.sp_rpy = (0.0, 0.0, 0.0)
        self.sp_thrust = 0.0
        self.sp_yaw_rate: float | None = None
        self.sp_t = -math.inf
        self.sp_recent: deque[float] = deque(maxlen=16)
        self.failsafe = False
        self.hold_z = 0.0
        self.hold_yaw = 0.0
        self.ground_since: float | None = None
        self._next_hb = 0.0
        self._next_tel = 0.0

    # -- modes --------------------------------------------------------------------------
    @property
    def guided(self) -> bool:
        """In the mode that takes SET_ATTITUDE_TARGET (GUIDED/GUIDED_NOGPS or OFFBOARD)."""
        if self.px4:
            return self.mode == px4_custom_mode(PX4_MAIN_OFFBOARD)
        return self.mode in (ARDUPILOT_MODES["GUIDED"], ARDUPILOT_MODES["GUIDED_NOGPS"])

    @property
    def landing(self) -> bool:
        """In LAND (ArduPilot) / AUTO.LAND (PX4)."""
        if self.px4:
            return self.mode == px4_custom_mode(PX4_MAIN_AUTO, PX4_SUB_AUTO_LAND)
        return self.mode == ARDUPILOT_MODES["LAND"]

    def event(self, t: float, name: str) -> None:
        """Record an event at simulation time t."""
        self.log.events.append((t, name))
        _log.debug("%s t=%.2f %s", self.name, t, name)

    # -- MAVLink in ---------------------------------------------------------------------
    def poll(self, t: float) -> None:
        """Handle every datagram waiting on the socket."""
        for _ in range(256):
            try:
                msg = self.conn.recv_msg()
            except OSError:
                return
            if msg is None:
                return
            self._handle(msg, t)

    def _ack(self, command: int, result: int) -> None:
        self.conn.mav.command_ack_send(command, result)

    def _handle(self, msg: object, t: float) -> None:
        kind = msg.get_type()  # type: ignore[attr-defined]
        if kind == "SET_ATTITUDE_TARGET":
            self._on_attitude_target(msg, t)
        elif kind == "HEARTBEAT":
            self.log.heartbeats_rx += 1
        elif kind == "COMMAND_LONG":
            self._on_command(msg, t)
        elif kind == "VISION_POSITION_ESTIMATE":
            self.log.vision += 1
            self.log.last_vision_wall = time.monotonic()
        elif kind == "ODOMETRY":
            self.log.odometry += 1
            self.log.last_vision_wall = time.monotonic()
        elif kind == "PARAM_SET":
            name = msg.param_id  # type: ignore[attr-defined]
            if name in self.params_table:
                self.params_table[name] = float(msg.param_value)  # type: ignore[attr-defined]
            self._send_param(name)
        elif kind == "PARAM_REQUEST_READ":
            self._send_param(msg.param_id)  # type: ignore[attr-defined]

    def _send_param(self, name: str) -> None:
        if name in self.params_table:
            self.conn.mav.param_value_send(
                name.encode(), self.params_table[name], mav.MAV_PARAM_TYPE_REAL32,
                len(self.params_table), list(self.params_table).index(name),
            )

    def _on_attitude_target(self, m: object, t: float) -> None:
        """SET_ATTITUDE_TARGET: refuse non-finite or non-unit q; accept when armed and guided."""
        q = np.array(m.q, dtype=np.float64)  # type: ignore[attr-defined]
        thrust = float(m.thrust)  # type: ignore[attr-defined]
        yaw_rate = float(m.body_yaw_rate)  # type: ignore[attr-defined]
        mask = int(m.type_mask)  # type: ignore[attr-defined]
        if not (np.all(np.isfinite(q)) and math.isfinite(thrust) and math.isfinite(yaw_rate)):
            self.log.rejected_nonfinite += 1
            self.event(t, "rejected_nonfinite")
            return
        if not quat_is_unit(q):
            self.log.rejected_quat += 1
            self.event(t, "rejected_quaternion")
            return
        self.sp_recent.append(t)
        self.log.setpoint_times.append(time.monotonic())
        if not self.guided or not self.armed:
            self.log.rejected_mode += 1
            return
        roll, pitch, yaw = euler_from_quat(quat_normalize(q))
        self.sp_rpy = (roll, pitch, yaw)
        self.sp_thrust = min(max(thrust, 0.0), 1.0)
        self.sp_yaw_rate = yaw_rate if mask & 4 == 0 else None
        self.sp_t = t
        self.log.setpoints += 1
        self.log.last_thrust, self.log.last_q, self.log.last_type_mask = thrust, q, mask
        self.log.last_setpoint_wall = time.monotonic()
        if self.failsafe:
            self.failsafe = False
            self.event(t, "setpoints_resumed")

    def _on_command(self, m: object, t: float) -> None:
        """COMMAND_LONG: arm/disarm and set mode, each answered by COMMAND_ACK."""
        cmd = int(m.command)  # type: ignore[attr-defined]
        p1, p2, p3 = (float(m.param1), float(m.param2),  # type: ignore[attr-defined]
                      float(m.param3))  # type: ignore[attr-defined]
        if cmd == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            if p1 >= 0.5:
                self.armed = True
                self.ground_since = t
                self.sp_t = max(self.sp_t, t)  # the set-point timeout starts at arming
                self.event(t, "armed")
                self._ack(cmd, mav.MAV_RESULT_ACCEPTED)
            elif self.fleet.on_ground(self.i) or int(p2) == FORCE_DISARM_MAGIC:
                self.armed = False
                self.event(t, "disarmed")
                self._ack(cmd, mav.MAV_RESULT_ACCEPTED)
            else:
                self._ack(cmd, mav.MAV_RESULT_DENIED)
        elif cmd == mav.MAV_CMD_DO_SET_MODE:
            self._ack(cmd, self._set_mode(int(p2), int(p3), t))
        else:
            self._ack(cmd, mav.MAV_RESULT_UNSUPPORTED)

    def _set_mode(self, p2: int, p3: int, t: float) -> int:
        """MAV_CMD_DO_SET_MODE for this flavour; returns the MAV_RESULT."""
        if self.px4:
            new = px4_custom_mode(p2, p3 if p2 == PX4_MAIN_AUTO else 0)
            if p2 == PX4_MAIN_OFFBOARD:
                recent = [s for s in self.sp_recent if t - s <= 1.0]
                if len(recent) < 3:
                    self.event(t, "offboard_refused")
                    return mav.MAV_RESULT_DENIED
            elif new != px4_custom_mode(PX4_MAIN_AUTO, PX4_SUB_AUTO_LAND) and p2 != 1:
                return mav.MAV_RESULT_UNSUPPORTED
        else:
            if p2 not in ARDUPILOT_MODES.values():
                return mav.MAV_RESULT_UNSUPPORTED
            new = p2
        if new != self.mode:
            self.mode = new
            self.failsafe = False
            self.sp_t = t  # grace period: a fresh mode starts its set-point timeout now
            self.event(t, "mode_land" if self.landing else f"mode_{new}")
            if self.landing:
                self.event(t, "land")
        return mav.MAV_RESULT_ACCEPTED

    # -- autopilot ----------------------------------------------------------------------
    def targets(self, t: float) -> tuple[float, float, float, float, float | None]:
        """(roll, pitch, yaw [rad NED], thrust 0..1, yaw-rate feed-forward) for this tick."""
        f, i, p = self.fleet, self.i, self.params
        z, vz = float(f.p[i, 2]), float(f.v[i, 2])
        yaw_now = float(f.att[i, 2])
        if not self.armed:
            return 0.0, 0.0, yaw_now, 0.0, None
        if self.landing:
            if f.on_ground(i):
                if self.ground_since is None:
                    self.ground_since = t
                elif t - self.ground_since > 0.5:
                    self.armed = False
                    self.event(t, "landed")
                    self.event(t, "disarmed")
            else:
                self.ground_since = None
            thrust = p.hover_thrust * (1.0 + 0.4 * (vz - p.land_speed))  # NED: vz > 0 is down
            return 0.0, 0.0, self.hold_yaw, min(max(thrust, 0.0), 1.0), None
        self.hold_yaw = yaw_now if not self.failsafe else self.hold_yaw
        if not self.guided:
            return 0.0, 0.0, yaw_now, 0.0, None  # no RC: idle
        if t - self.sp_t > p.setpoint_timeout:
            if not self.failsafe:
                self.failsafe = True
                self.hold_z, self.hold_yaw = z, yaw_now
                self.event(t, "setpoint_timeout")
            return 0.0, 0.0, self.hold_yaw, self._climb_thrust(0.0, z - self.hold_z), None
        roll, pitch, yaw = self.sp_rpy
        if self.sp_yaw_rate is not None:
            yaw = wrap_pi(yaw + self.sp_yaw_rate * (t - self.sp_t))
        thrust = self.sp_thrust
        if not self.px4 and int(self.params_table["GUID_OPTIONS"]) & GUID_OPTIONS_REAL_THRUST == 0:
            climb = (thrust - 0.5) * 2.0 * p.pilot_speed  # ArduCopter default: climb rate [m/s up]
            thrust = self._climb_thrust(climb, 0.0)
        return roll, pitch, yaw, thrust, None

    def _climb_thrust(self, climb_up: float, z_err: float) -> float:
        """Internal vertical loop: thrust for climb rate [m/s up] plus altitude hold (NED z err)."""
        p = self.params
        vz = float(self.fleet.v[self.i, 2])
        a_up = 2.0 * (climb_up + vz) + 1.5 * z_err  # NED: −vz is up
        return min(max(p.hover_thrust * (1.0 + a_up / p.g), 0.0), 1.0)

    # -- MAVLink out --------------------------------------------------------------------
    def telemetry(self, t: float) -> None:
        """Send HEARTBEAT (1 Hz) and ATTITUDE + LOCAL_POSITION_NED (telemetry rate) when due."""
        f, i = self.fleet, self.i
        ms = int(max(t, 0.0) * 1000) & 0xFFFFFFFF
        if t >= self._next_hb:
            self._next_hb = t + 1.0
            base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            if self.armed:
                base |= mav.MAV_MODE_FLAG_SAFETY_ARMED
            status = mav.MAV_STATE_ACTIVE if self.armed else mav.MAV_STATE_STANDBY
            ap = mav.MAV_AUTOPILOT_PX4 if self.px4 else mav.MAV_AUTOPILOT_ARDUPILOTMEGA
            self.conn.mav.heartbeat_send(mav.MAV_TYPE_QUADROTOR, ap, base, self.mode, status)
        if t >= self._next_tel:
            self._next_tel = t + 1.0 / self.params.telemetry_rate
            r, pch, y = (float(a) for a in f.att[i])
            wr, wp, wy = (float(a) for a in f.rates[i])
            self.conn.mav.attitude_send(ms, r, pch, y, wr, wp, wy)
            px, py, pz = (float(a) for a in f.p[i])
            vx, vy, vz = (float(a) for a in f.v[i])
            self.conn.mav.local_position_ned_send(ms, px, py, pz, vx, vy, vz)

    def close(self) -> None:
        """Close the UDP socket."""
        self.conn.close()


class SimFleet:
    """n simulated quadrotors stepped together against a :class:`Clock` on one thread.

    Args:
        names: vehicle names (drone ids).
        clock: the shared simulation clock.
        params: vehicle parameters (one for all, or one per vehicle).
        ports: UDP port per vehicle (0 = any free port; see :attr:`SimQuad.port`).
        start: initial positions [m, ENU] (n, 3); yaw0 initial headings [rad, ENU].
        dt: physics step [s sim]; tick_s: wall period of the loop [s].
        seed: seed of the mocap noise.

    ``max_catchup`` [s sim]: a loop that falls further behind the clock than this slips the
    clock (if it has ``slip``) rather than jumping; ``slipped`` totals the time given up.
    """

    def __init__(self, names: list[str], clock: Clock, params: VehicleParams | list[VehicleParams],
                 ports: list[int] | None = None, start: Array | None = None,
                 yaw0: list[float] | None = None, host: str = "127.0.0.1", dt: float = 0.0025,
                 tick_s: float = 0.002, seed: int = 0) -> None:
        n = len(names)
        self.names, self.clock, self.dt, self.tick_s = list(names), clock, dt, tick_s
        plist = params if isinstance(params, list) else [params] * n
        if len(plist) != n:
            raise ValueError("one VehicleParams per vehicle, or a single one")
        self.params = plist
        self.p = np.zeros((n, 3)) if start is None else np.array(
            [ned_for(s) for s in np.asarray(start, dtype=np.float64).reshape(n, 3)])
        self.v = np.zeros((n, 3))
        self.att = np.zeros((n, 3))  # roll, pitch, yaw [rad] NED/FRD
        if yaw0 is not None:
            self.att[:, 2] = [wrap_pi(math.pi / 2 - y) for y in yaw0]
        self.rates = np.zeros((n, 3))
        self.thrust = np.zeros(n)
        self._mass = np.array([p.mass for p in plist])
        self._tmax = np.array([p.max_thrust for p in plist])
        self._drag = np.array([p.drag for p in plist])
        self._tau_att = np.array([p.tau_att for p in plist])
        self._tau_thr = np.array([p.tau_thrust for p in plist])
        self._g = plist[0].g
        self.t = clock.now()
        ports = ports or [0] * n
        self.quads: list[SimQuad] = []
        try:
            for i, name in enumerate(names):
                self.quads.append(SimQuad(self, i, name, plist[i], host, ports[i], sysid=i + 1))
        except OSError:
            self.close()
            raise
        self.rng = np.random.default_rng(seed)
        lat = max(p.mocap_latency for p in plist)
        self._hist: deque[tuple[float, Array, Array, Array]] = deque(
            maxlen=max(2, int(lat / dt) + 4))
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.steps = 0
        self.max_lag = 0.0
        self.max_catchup = 0.05
        self.slipped = 0.0
        self._record()

    # -- physics ------------------------------------------------------------------------
    def on_ground(self, i: int) -> bool:
        """Vehicle i rests on the ground (z ≥ −1 mm NED, not climbing)."""
        return bool(self.p[i, 2] >= -1e-3 and self.v[i, 2] >= -1e-3)

    def _substep(self, tgt: Array, dt: float) -> None:
        """One physics step of dt [s]: first-order attitude/thrust, Newton in NED, ground."""
        a_att = 1.0 - np.exp(-dt / self._tau_att)
        a_thr = 1.0 - np.exp(-dt / self._tau_thr)
        prev = self.att.copy()
        d_yaw = (tgt[:, 2] - self.att[:, 2] + np.pi) % (2 * np.pi) - np.pi
        self.att[:, 0:2] += (tgt[:, 0:2] - self.att[:, 0:2]) * a_att[:, None]
        self.att[:, 2] = (self.att[:, 2] + d_yaw * a_att + np.pi) % (2 * np.pi) - np.pi
        d = self.att - prev
        d[:, 2] = (d[:, 2] + np.pi) % (2 * np.pi) - np.pi
        self.rates = d / dt
        self.thrust += (tgt[:, 3] - self.thrust) * a_thr
        r, pch, y = self.att[:, 0], self.att[:, 1], self.att[:, 2]
        cr, sr, cp, sp = np.cos(r), np.sin(r), np.cos(pch), np.sin(pch)
        cy, sy = np.cos(y), np.sin(y)
        z_b = np.stack([cy * sp * cr + sy * sr, sy * sp * cr - cy * sr, cp * cr], axis=1)
        force = -(self._tmax * self.thrust)[:, None] * z_b - self._drag[:, None] * self.v
        acc = force / self._mass[:, None]
        acc[:, 2] += self._g
        self.v += acc * dt
        self.p += self.v * dt
        below = self.p[:, 2] >= 0.0
        if below.any():  # ground contact: no penetration, no sliding
            self.p[below, 2] = 0.0
            self.v[below] = np.where(self.v[below, 2:3] > 0.0, 0.0, self.v[below])
            self.v[below, 0:2] = 0.0

    def _record(self) -> None:
        """Keep (t, p, v, attitude) for the mocap latency look-up."""
        self._hist.append((self.t, self.p.copy(), self.v.copy(), self.att.copy()))

    def step_to(self, t_end: float) -> int:
        """Advance physics to simulation time t_end [s] in steps of dt; returns steps taken."""
        n = 0
        with self._lock:
            tgt = np.zeros((len(self.quads), 4))
            while self.t + self.dt <= t_end + 1e-12:
                for q in self.quads:
                    r, pch, y, thr, _ = q.targets(self.t)
                    tgt[q.i] = (r, pch, y, thr)
                self._substep(tgt, self.dt)
                self.t += self.dt
                self._record()
                n += 1
        self.steps += n
        return n

    # -- mocap --------------------------------------------------------------------------
    def mocap(self, i: int) -> MocapSample:
        """Vehicle i's pose as motion capture sees it: delayed by its mocap latency, noisy."""
        p = self.params[i]
        with self._lock:
            target = self.t - p.mocap_latency
            rec = self._hist[-1]
            for rec_i in reversed(self._hist):
                rec = rec_i
                if rec_i[0] <= target + 1e-9:
                    break
            t, pos, vel, att = rec[0], rec[1][i].copy(), rec[2][i].copy(), rec[3][i].copy()
        if p.mocap_noise_pos > 0:
            pos = pos + self.rng.normal(0.0, p.mocap_noise_pos, 3)
        if p.mocap_noise_att > 0:
            att = att + self.rng.normal(0.0, p.mocap_noise_att, 3)
        q_ned = quat_from_euler(float(att[0]), float(att[1]), float(att[2]))
        return MocapSample(t, ned_to_enu(pos), ned_to_enu(vel), quat_ned_frd_to_enu_flu(q_ned))

    def position_enu(self, i: int) -> Array:
        """True position of vehicle i [m, ENU]."""
        with self._lock:
            return ned_to_enu(self.p[i])

    # -- loop ---------------------------------------------------------------------------
    def tick(self) -> None:
        """One loop iteration: read MAVLink, step physics to the clock, send telemetry.

        If the loop fell more than ``max_catchup`` [s sim] behind (the machine is overloaded)
        and the clock can slip, simulated time is held back instead of jumping: the whole
        simulation runs slower than asked (time dilation) but stays consistent.
        """
        now = self.clock.now()
        behind = now - self.t
        slip = getattr(self.clock, "slip", None)
        if behind > self.max_catchup and slip is not None:
            slip(behind - self.dt)
            self.slipped += behind - self.dt
            now = self.clock.now()
        for q in self.quads:
            q.poll(self.t)
        self.step_to(now)
        self.max_lag = max(self.max_lag, now - self.t)
        for q in self.quads:
            q.telemetry(self.t)

    def _run(self) -> None:
        while not self._stop.is_set():
            t0 = time.monotonic()
            try:
                self.tick()
            except Exception:
                _log.exception("simulator tick failed")
                raise
            rest = self.tick_s - (time.monotonic() - t0)
            if rest > 0:
                self._stop.wait(rest)

    def start(self) -> SimFleet:
        """Run the loop on a daemon thread."""
        self.t = self.clock.now()
        self._thread = threading.Thread(target=self._run, name="sim-fleet", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop and join the loop thread."""
        self._stop.set()
        if self._thread is not None and self._thread.is_alive():
            self._thread.join(5.0)

    def close(self) -> None:
        """Stop the loop and close every socket."""
        self.stop()
        for q in self.quads:
            q.close()

    def __enter__(self) -> SimFleet:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()


class FleetClock:
    """Simulation time as the physics has reached it (``fleet.t``), paced by the fleet's clock.

    In simulation this is *the* mission clock: the ground station publishes it and stamps
    poses with it, so a pose is never "stale" just because the physics thread was briefly
    starved, and followers never run ahead of the physics by more than their extrapolation.
    """

    def __init__(self, fleet: SimFleet) -> None:
        self.fleet = fleet

    @property
    def time_scale(self) -> float:
        """Pacing: simulation seconds per wall second."""
        return float(getattr(self.fleet.clock, "time_scale", 1.0))

    @property
    def scale(self) -> float:
        """Alias of :attr:`time_scale`."""
        return self.time_scale

    def now(self) -> float:
        """Physics time [s sim]."""
        return self.fleet.t

    def wall(self, dt: float) -> float:
        """Wall seconds of ``dt`` simulation seconds."""
        return max(0.0, dt) / self.time_scale

    def sleep(self, dt: float) -> None:
        """Sleep ``dt`` simulation seconds (nominal pace)."""
        time.sleep(self.wall(dt))


def ned_for(p_enu: Array) -> Array:
    """ENU position [m] → NED, clamped to the ground (z ≥ 0 up)."""
    x, y, z = (float(a) for a in p_enu)
    return np.array([y, x, -max(z, 0.0)])
