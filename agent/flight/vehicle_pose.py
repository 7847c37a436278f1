"""The flown vehicle as a pose source (thesis chapter 6): motion capture in, MAVLink out.

:class:`MavlinkPoseSource` satisfies the runtime's pose-source contract
(:class:`agent.runtime.shell.pose.PoseSource`, whose kinematic implementation integrates eq. 5.1
instead): ``current() -> (p, v, t)`` and ``command(p_dot, omega, dt)``.

* ``current``: position p [m, ENU] from the latest mocap pose, camera direction v from the
  latitude-longitude form (eq. 2.3) with ψ = the measured yaw (eq. 2.4: the longitude is the
  yaw) and θ = the simulated camera tilt, t = the pose's time [s sim].
* ``command``: ṗ* goes to the speed loop (figure 6.1), ψ̇* = ω₃ (eq. 2.4; with the exact
  correction −tan θ (cos ψ ω₁ + sin ψ ω₂) when the tilt θ ≠ 0) to the yaw, and θ
  integrates θ̇ from eq. 2.5: simulated (section 6.1), or, with a gimbal
  (:class:`~agent.flight.gimbal.GimbalClient` that found one), the commanded tilt, kept
  within the gimbal's pitch limits and rate and sent to it; ``current`` then reports the
  measured tilt (GIMBAL_DEVICE_ATTITUDE_STATUS) while it is fresh. A command lasts ``dt``
  plus a grace period, then the controller holds position; zero commands hold at once;
  non-finite commands are refused (counted in ``rejected``) and the vehicle holds.
* :meth:`hold` / :meth:`goto`: the position + angle hold of figure 6.2 (trading, initial
  positioning).
* :meth:`tilt_limits` (the gimbal's pitch range, a constraint of the planner: None with a
  simulated tilt) and :meth:`battery` (what the autopilot reports, published in the agent's
  state): what the runtime asks of a vehicle besides its pose (:mod:`agent.runtime.shell.pose`).

It never touches sockets itself: poses come from a provider callable (e.g.
:class:`ZenohMocapFeed`, or a simulator in tests) and set-points leave through a
:class:`~agent.flight.mavlink_driver.MavlinkDriver`.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from agent.core.orientation import direction_from_angles
from agent.core.tilt import TiltLimits
from agent.flight.battery import BatteryReader
from agent.flight.controllers import LatitudeIntegrator, yaw_rate_of
from agent.flight.driver_types import PoseProvider, PoseSample
from agent.flight.frames import wrap_pi, yaw_from_quat
from agent.flight.gimbal import GimbalClient
from agent.flight.mavlink_driver import MavlinkDriver
from agent.flight.monitor import MocapAge
from agent.net.contract import Declared, Transport
from agent.wire.ground import CLOCK_CODEC, MOCAP_CODEC
from agent.wire.keys import all_agents, clock_key, mocap_key
from agent.wire.peer import Battery

_log = logging.getLogger(f"viscover.{__name__}")
Array = NDArray[np.float64]


class ZenohMocapFeed:
    """Latest mocap pose of one drone from ``viscover/<m>/mocap/<drone>`` (a pose provider).

    ``on_pose`` (e.g. ``driver.notify_pose``) runs on the transport's worker after each
    accepted pose. Poses that fail to decode, are for another drone, or are older than the
    latest one are dropped (counted in ``dropped``).

    ``mocap_age`` (:class:`~agent.flight.monitor.MocapAge`, silence bound ``silence_s`` wall
    seconds) hears the ground station's clock (``viscover/<m>/clock``) and the poses' stamps,
    so the driver reading this feed judges a pose's age on the station's own clock.
    """

    def __init__(self, transport: Transport, mission: str, drone: str,
                 on_pose: Callable[[], None] | None = None, silence_s: float = 0.5) -> None:
        self.drone = drone
        self.on_pose = on_pose
        self._lock = threading.Lock()
        self._latest: PoseSample | None = None
        self.received = 0
        self.dropped = 0
        self.mocap_age = MocapAge(silence_s)
        self._clock_sub: Declared = transport.subscribe(clock_key(mission), self._on_clock)
        try:
            self._sub: Declared = transport.subscribe(mocap_key(mission, drone),
                                                      self._on_sample)
        except BaseException:
            self._clock_sub.undeclare()
            raise

    def _on_clock(self, key: str, payload: bytes) -> None:
        msg = CLOCK_CODEC.decode(payload, key)
        if msg is not None and math.isfinite(msg.t):
            self.mocap_age.heard(msg.t)

    def _on_sample(self, key: str, payload: bytes) -> None:
        rx = time.monotonic()
        msg = MOCAP_CODEC.decode(payload, key)
        if msg is None or msg.drone != self.drone or len(msg.p) != 3 or len(msg.q) != 4 \
                or len(msg.v) != 3:
            self.dropped += 1
            return
        sample = PoseSample(msg.t, np.array(msg.p), np.array(msg.v), np.array(msg.q), rx)
        if math.isfinite(msg.t):
            self.mocap_age.heard(msg.t)
        with self._lock:
            if self._latest is not None and sample.t <= self._latest.t:
                self.dropped += 1
                return
            self._latest = sample
            self.received += 1
        if self.on_pose is not None:
            self.on_pose()

    def __call__(self) -> PoseSample | None:
        """The latest pose, or None before the first one."""
        with self._lock:
            return self._latest

    def close(self) -> None:
        """Unsubscribe."""
        self._sub.undeclare()
        self._clock_sub.undeclare()


class MocapNeighbours:
    """Latest mocap positions of every other drone of the mission, from
    ``viscover/<m>/mocap/*`` (the ground station's truth; it does not depend on the other
    agents' processes still running). Used to keep R_s while flying home after the mission.
    """

    def __init__(self, transport: Transport, mission: str, me: str) -> None:
        self.me = me
        self._lock = threading.Lock()
        self._latest: dict[str, tuple[float, Array]] = {}  # drone -> (wall rx [s], p [m])
        self._sub: Declared = transport.subscribe(all_agents(mission, "mocap"), self._on_sample)

    def _on_sample(self, key: str, payload: bytes) -> None:
        msg = MOCAP_CODEC.decode(payload, key)
        if msg is None or msg.drone == self.me or len(msg.p) != 3:
            return
        with self._lock:
            self._latest[msg.drone] = (time.monotonic(), np.array(msg.p, dtype=np.float64))

    def positions(self, max_age_s: float = 1.0) -> Array:
        """Positions [m, ENU] (n, 3) of the other drones heard within ``max_age_s`` wall
        seconds."""
        now = time.monotonic()
        with self._lock:
            fresh = [p for rx, p in self._latest.values() if now - rx <= max_age_s]
        return np.array(fresh).reshape(-1, 3)

    def close(self) -> None:
        """Unsubscribe."""
        self._sub.undeclare()


class MavlinkPoseSource:
    """``PoseSource`` of a real (or simulated) quadcopter: mocap in, MAVLink set-points out.

    Args:
        driver: a started and engaged driver (its controller is driven from here).
        pose: the pose provider (usually the same one the driver reads).
        latitude0: initial camera latitude θ [rad].
        grace_s: how long past ``dt`` a velocity command stays active [s sim].
        gimbal: the vehicle's gimbal (None, or one without hardware: θ simulated).
        battery: the vehicle's battery (None: not read).
    """

    def __init__(self, driver: MavlinkDriver, pose: PoseProvider, latitude0: float = 0.0,
                 grace_s: float = 0.3, gimbal: GimbalClient | None = None,
                 battery: BatteryReader | None = None) -> None:
        self.driver = driver
        self.battery_reader = battery
        self.controller = driver.controller
        self.pose = pose
        self.latitude = LatitudeIntegrator(theta=latitude0)
        self.grace_s = grace_s
        self.rejected = 0
        self.gimbal = gimbal if gimbal is not None and gimbal.present else None
        if self.gimbal is not None:
            self.latitude.theta = self.gimbal.set_tilt(latitude0)

    def tilt_limits(self) -> TiltLimits | None:
        """The gimbal's pitch range [rad] for the planner; None with a simulated tilt (the
        thesis: no limit)."""
        if self.gimbal is None:
            return None
        lim = self.gimbal.limits
        return TiltLimits.of(lim.pitch_min, lim.pitch_max)

    def battery(self) -> Battery | None:
        """The battery's charge [%] and voltage [V] as last reported (None: not read)."""
        r = self.battery_reader
        return None if r is None else r.state.published()

    def tilt(self) -> float:
        """The camera tilt θ [rad]: the gimbal's measured one when fresh, else commanded."""
        return self.latitude.theta if self.gimbal is None else self.gimbal.tilt()

    def _sample(self) -> PoseSample:
        s = self.pose()
        if s is None:
            raise RuntimeError("no mocap pose received yet")
        return s

    def current(self) -> tuple[Array, Array, float]:
        """(p [m, ENU], unit camera direction v (eq. 2.3: θ = :meth:`tilt`, ψ = yaw),
        t [s sim])."""
        s = self._sample()
        psi = yaw_from_quat(s.q)
        return s.p.copy(), direction_from_angles(self.tilt(), psi), s.t

    def command(self, p_dot: ArrayLike, omega: ArrayLike, dt: float) -> None:
        """Section 6.1: ṗ* [m/s ENU] to the speed loop, ψ̇* = ω₃ (eq. 2.4), θ += θ̇ dt
        (eq. 2.5) for ``dt`` [s]; zero → hold; non-finite → refused, hold."""
        v = np.asarray(p_dot, dtype=np.float64)
        w = np.asarray(omega, dtype=np.float64)
        if v.shape != (3,) or w.shape != (3,) or not (np.all(np.isfinite(v))
                                                       and np.all(np.isfinite(w))
                                                       and math.isfinite(dt)):
            self.rejected += 1
            _log.error("refused a non-finite command (p_dot=%s omega=%s dt=%s)", v, w, dt)
            self.hold()
            return
        if not (np.any(v) or np.any(w)):
            if self.controller.mode != "hold":
                self.hold()
            return
        s = self._sample()
        psi = yaw_from_quat(s.q)
        yaw_rate = yaw_rate_of(w, self.latitude.theta, psi)  # eq. 2.4 (exact form)
        before = self.latitude.theta
        self.latitude.step(w, psi, dt)
        if self.gimbal is not None:  # within the gimbal's rate and limits, then commanded
            lim = self.gimbal.limits
            step = lim.rate_max * max(dt, 0.0)
            wanted = min(max(self.latitude.theta, before - step), before + step)
            self.latitude.theta = self.gimbal.set_tilt(wanted)
        self.controller.set_velocity(v, yaw_rate, until=s.t + dt + self.grace_s)

    def hold(self, p: ArrayLike | None = None, yaw: float | None = None) -> None:
        """Figure 6.2: hold position p [m, ENU] (None: where it is) and yaw ψ [rad, ENU]."""
        self.controller.set_hold(p, yaw)

    def goto(self, p: ArrayLike, yaw: float, tol: float = 0.1, yaw_tol: float = 0.1,
             timeout_s: float = 30.0, sleep: Callable[[float], None] | None = None) -> bool:
        """Initial positioning (figure 6.2): hold at p, ψ and wait (sim s) until within
        ``tol`` [m] and ``yaw_tol`` [rad]; False on timeout or once the vehicle left our
        control (``driver.released``)."""
        self.hold(p, yaw)
        target = self.controller.p_hold
        t_end = self.driver.clock.now() + timeout_s
        pause = sleep or (lambda dt: time.sleep(self.driver.clock.wall(dt)))
        while self.driver.clock.now() < t_end:
            if self.driver.released is not None:
                return False  # the vehicle left our control: a pilot or failsafe has it
            s = self.pose()
            if s is not None and target is not None:
                close = float(np.linalg.norm(s.p - target)) <= tol
                if close and abs(wrap_pi(yaw_from_quat(s.q) - yaw)) <= yaw_tol:
                    return True
            pause(0.05)
        return False
