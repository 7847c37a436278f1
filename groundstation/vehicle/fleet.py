"""The simulated fleet: n autopilots on UDP, one pure dynamics model, one thread, one clock.

Each vehicle listens on ``udp:host:port`` and answers every peer that sends to it (all of its
messages go to every peer heard from, as a SITL serial port shared by a ground station and a
companion would); with ``gcs = "udp:host:port"`` it also streams to that address without
being asked, as SITL's ``--out``. The loop (:meth:`SimFleet.tick`) reads MAVLink, steps the
dynamics in fixed ``dt`` up to the clock, and sends what is due. An exception escaping a
message, a vehicle or a tick is counted and logged by a ``HandlerGuard``; the loop goes on.

The fleet is also the motion-capture source of the ground station in simulation:
:meth:`SimFleet.mocap` returns each vehicle's true pose delayed by ``mocap_latency`` with
Gaussian noise and dropouts (seeded), in mission frames (ENU world, FLU body).
"""

from __future__ import annotations

import contextlib
import math
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agent.clock import Clock
from agent.flight.frames import ned_to_enu, quat_from_euler, quat_ned_frd_to_enu_flu, wrap_pi
from agent.wire.mavlink import mavlink as mav
from groundstation.vehicle import dynamics
from groundstation.vehicle.autopilot import Autopilot
from groundstation.vehicle.dynamics import FleetParams, VehicleState
from groundstation.vehicle.inbound import HandlerGuard
from groundstation.vehicle.params import VehicleParams

Array = NDArray[np.float64]


@dataclass
class MocapSample:
    """One mocap observation in mission frames: time [s sim], position [m ENU], velocity
    [m/s ENU], attitude q = R_ENU←FLU (w, x, y, z)."""

    t: float
    p: Array
    v: Array
    q: Array


def parse_udp(address: str) -> tuple[str, int]:
    """``udp:host:port`` → (host, port)."""
    kind, host, port = address.split(":")
    if kind != "udp" or not port.isdigit():
        raise ValueError(f"expected udp:host:port, got {address!r}")
    return host, int(port)


class VehicleLink:
    """One vehicle's UDP endpoint: bound to ``host:port``; sends each message to every peer
    heard from and to the configured ground-station addresses."""

    def __init__(self, host: str, port: int, sysid: int, gcs: list[tuple[str, int]]) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind((host, port))
        except OSError:
            self.sock.close()
            raise
        self.sock.setblocking(False)
        self.port: int = self.sock.getsockname()[1]
        self.gcs = list(gcs)
        self.peers: dict[tuple[str, int], float] = {}
        self.mav = mav.MAVLink(self, srcSystem=sysid, srcComponent=1)
        self.mav.robust_parsing = True
        self.sent = 0

    def write(self, buf: bytes) -> None:
        """Send one encoded message to the peers and the ground stations."""
        for addr in [*self.gcs, *(a for a in self.peers if a not in self.gcs)]:
            try:
                self.sock.sendto(buf, addr)
                self.sent += 1
            except OSError:  # e.g. ECONNREFUSED reported for an earlier datagram
                pass

    def receive(self, limit: int = 256) -> list[Any]:
        """Every MAVLink message waiting (at most ``limit`` datagrams)."""
        out: list[Any] = []
        for _ in range(limit):
            try:
                data, addr = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                continue  # ICMP errors of earlier sends surface here on Linux
            self.peers[addr] = time.monotonic()
            try:
                out.extend(self.mav.parse_buffer(data) or [])
            except mav.MAVError:
                continue
        return out

    def close(self) -> None:
        """Close the socket."""
        self.sock.close()


class SimFleet:
    """n simulated quadrotors stepped together against a :class:`Clock` on one thread.

    Args:
        names: vehicle names (drone ids).
        clock: the shared simulation clock.
        params: vehicle parameters (one for all, or one per vehicle).
        ports: UDP port per vehicle (0 = any free port; see :attr:`Autopilot.port`).
        start: initial positions [m, ENU] (n, 3); yaw0 initial headings [rad, ENU].
        dt: physics step [s sim]; tick_s: wall period of the loop [s].
        seed: seed of every random process (gusts, sensor and mocap noise, dropouts).

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
        self.physics = FleetParams.of(plist)
        p0 = np.zeros((n, 3)) if start is None else np.array(
            [ned_for(s) for s in np.asarray(start, dtype=np.float64).reshape(n, 3)])
        yaws = None if yaw0 is None else np.array([wrap_pi(math.pi / 2 - y) for y in yaw0])
        self.state: VehicleState = dynamics.initial_state(p0, yaws)
        self.rng = np.random.default_rng(seed)
        self._gusty = bool(np.any(self.physics.gust_std > 0))
        self.t = clock.now()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.guard = HandlerGuard()  # the last line of defence of every vehicle and the loop
        ports = ports or [0] * n
        self.quads: list[Autopilot] = []
        try:
            for i, name in enumerate(names):
                out = plist[i].gcs
                gcs = [parse_udp(out)] if out else []
                link = VehicleLink(host, ports[i], i + 1, gcs)
                try:
                    ap = Autopilot(name, i, i + 1, plist[i], link, self._truth,
                                   np.random.default_rng([seed, i, 1]), self.guard, seed)
                except Exception:
                    link.close()
                    raise
                self.quads.append(ap)
        except (OSError, ValueError):
            self.close()
            raise
        self._mocap_rng = [np.random.default_rng([seed, i, 2]) for i in range(n)]
        self._last_mocap: list[MocapSample | None] = [None] * n
        lat = max(p.mocap_latency for p in plist)
        self._hist: deque[tuple[float, Array, Array, Array]] = deque(
            maxlen=max(2, int(lat / dt) + 4))
        self._armed_at: list[float | None] = [None] * n  #: first arming [s sim]
        self._mass_stepped = [False] * n
        self.steps = 0
        self.max_lag = 0.0
        self.max_catchup = 0.05
        self.slipped = 0.0
        self._record()

    def _truth(self) -> VehicleState:
        return self.state

    @property
    def handler_errors(self) -> int:
        """Exceptions caught by the guard (0: every message was answered by its handler)."""
        return self.guard.count

    # -- views of the state (NED/FRD arrays, mutable in place by tests) -----------------
    @property
    def p(self) -> Array:
        """Positions (n, 3) [m; world NED]."""
        return self.state.p

    @property
    def v(self) -> Array:
        """Velocities (n, 3) [m/s; world NED]."""
        return self.state.v

    @property
    def att(self) -> Array:
        """Roll, pitch, yaw (n, 3) [rad; NED/FRD]."""
        return self.state.att

    @property
    def rates(self) -> Array:
        """Euler angle rates (n, 3) [rad/s]."""
        return self.state.rates

    @property
    def thrust(self) -> Array:
        """Normalised thrust after the motor lag (n,)."""
        return self.state.thrust

    def on_ground(self, i: int) -> bool:
        """Vehicle i rests on the ground (z ≥ −1 mm NED, not climbing)."""
        return bool(dynamics.on_ground(self.state)[i])

    # -- physics ------------------------------------------------------------------------
    def _record(self) -> None:
        """Keep (t, p, v, attitude) for the mocap latency look-up."""
        s = self.state
        self._hist.append((self.t, s.p.copy(), s.v.copy(), s.att.copy()))

    def step_to(self, t_end: float) -> int:
        """Advance physics to simulation time t_end [s] in steps of dt; returns steps taken."""
        n = 0
        with self._lock:
            cmd = np.zeros((len(self.quads), 4))
            while self.t + self.dt <= t_end + 1e-12:
                for q in self.quads:
                    cmd[q.i] = q.targets(self.t)
                self.state.armed = np.array([q.armed for q in self.quads])
                noise = self.rng.standard_normal((len(self.quads), 3)) if self._gusty else None
                self.state = dynamics.step(self.state, cmd, self.physics, self.dt, noise)
                self.t += self.dt
                self._record()
                n += 1
        self.steps += n
        return n

    def set_mass(self, i: int, mass: float) -> None:
        """Vehicle i now weighs ``mass`` [kg] (a payload picked up or dropped in flight): its
        motors' maximum thrust stays, so its true hover thrust scales with the mass; the
        autopilot's hover-thrust parameter does not change (as on a real vehicle)."""
        if not mass > 0:
            raise ValueError("mass must be > 0")
        with self._lock:
            masses = self.physics.mass.copy()
            masses[i] = mass
            self.physics = replace(self.physics, mass=masses)

    def _scheduled_mass_steps(self) -> None:
        """Apply each vehicle's ``mass_step_after`` once it is due (per vehicle, not per
        landmark: a loop over a handful of quads)."""
        for q in self.quads:
            after = self.params[q.i].mass_step_after
            if after is None or self._mass_stepped[q.i]:
                continue
            if self._armed_at[q.i] is None and q.armed:
                self._armed_at[q.i] = self.t
            at = self._armed_at[q.i]
            if at is not None and self.t - at >= after:
                self._mass_stepped[q.i] = True
                self.set_mass(q.i, float(self.physics.mass[q.i])
                              * self.params[q.i].mass_step_factor)

    def true_hover_thrust(self, i: int) -> float:
        """The normalised thrust that balances vehicle i's weight now: m g / T_max."""
        ph = self.physics
        return float(ph.mass[i] * ph.g / ph.max_thrust[i])

    # -- mocap --------------------------------------------------------------------------
    def mocap(self, i: int) -> MocapSample:
        """Vehicle i's pose as motion capture sees it: delayed by its mocap latency, noisy;
        a dropped frame repeats the last delivered sample (same time stamp)."""
        p = self.params[i]
        rng = self._mocap_rng[i]
        last = self._last_mocap[i]
        if p.mocap_dropout > 0 and rng.random() < p.mocap_dropout and last is not None:
            return last
        with self._lock:
            target = self.t - p.mocap_latency
            rec = self._hist[-1]
            for rec_i in reversed(self._hist):
                rec = rec_i
                if rec_i[0] <= target + 1e-9:
                    break
            t, pos, vel, att = rec[0], rec[1][i].copy(), rec[2][i].copy(), rec[3][i].copy()
        if p.mocap_noise_pos > 0:
            pos = pos + rng.normal(0.0, p.mocap_noise_pos, 3)
        if p.mocap_noise_att > 0:
            att = att + rng.normal(0.0, p.mocap_noise_att, 3)
        q_ned = quat_from_euler(float(att[0]), float(att[1]), float(att[2]))
        s = MocapSample(t, ned_to_enu(pos), ned_to_enu(vel), quat_ned_frd_to_enu_flu(q_ned))
        self._last_mocap[i] = s
        return s

    def position_enu(self, i: int) -> Array:
        """True position of vehicle i [m, ENU]."""
        with self._lock:
            return ned_to_enu(self.state.p[i])

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
        self._scheduled_mass_steps()
        self.step_to(now)
        self.max_lag = max(self.max_lag, now - self.t)
        for q in self.quads:
            q.telemetry(self.t)

    def _run(self) -> None:
        while not self._stop.is_set():
            t0 = time.monotonic()
            try:
                self.tick()
            except Exception as exc:  # the fleet thread must not die
                self.guard.failed("sim-fleet", "tick", exc)
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
            with contextlib.suppress(OSError):
                q.link.close()

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
