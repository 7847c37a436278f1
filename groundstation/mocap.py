"""Pose sources of the ground station, behind one interface (:class:`MocapSource`).

* :class:`SimMocapSource`: the built-in simulator (:class:`groundstation.vehicle.fleet.SimFleet`),
  one simulated quadrotor per drone, with its configured mocap noise and latency.
* :class:`MotionCaptureSource`: real motion capture through the ``motioncapture`` package
  (libmotioncapture: vicon, optitrack, qualisys, vrpn, and ``mock`` for tests) with a
  rigid-body-name → drone-id map. Its world frame is taken as ENU-like, z up (Vicon and
  Qualisys default; set OptiTrack's up axis to z); velocities are finite differences.

``read(now)`` returns, per drone id, a *new* sample or None: a body that was not in the latest
frame, or whose frame was already returned, gives None, so a pose is never repeated.
:class:`Health` turns that into ``ok`` / ``stale`` / ``missing`` per drone.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from agent.clock import Clock
from agent.flight.frames import quat_normalize
from groundstation.vehicle.fleet import SimFleet

_log = logging.getLogger(f"viscover.{__name__}")
Array = NDArray[np.float64]

MOCAP_TYPES = ("mock", "vicon", "optitrack", "qualisys", "vrpn")

#: The one line when the ``motioncapture`` package is missing (an optional extra: it has no
#: aarch64 wheel).
NO_MOTIONCAPTURE = ("--source motioncapture needs the package motioncapture, which is not "
                    "installed: install viscover[mocap] (pip install 'viscover[mocap]')")


class MocapError(RuntimeError):
    """The motion-capture system cannot be used (unknown type, no connection); one line."""


def import_motioncapture() -> Any:
    """The ``motioncapture`` module, or :class:`MocapError` (:data:`NO_MOTIONCAPTURE`)."""
    try:
        import motioncapture
    except ImportError:
        raise MocapError(NO_MOTIONCAPTURE) from None
    return motioncapture


@dataclass
class BodySample:
    """A rigid body in one frame: capture time t [s sim], position p [m ENU], attitude q
    (w, x, y, z) R_ENU←FLU, velocity v [m/s ENU]."""

    t: float
    p: Array
    q: Array
    v: Array


class MocapSource(Protocol):
    """Where the station's poses come from."""

    kind: str
    drone_ids: list[str]

    def read(self, now: float) -> dict[str, BodySample | None]:
        """New samples per drone id since the last call (None: nothing new)."""

    def close(self) -> None:
        """Release the source (threads joined, sockets closed)."""


class SimMocapSource:
    """Mocap from the simulator: each vehicle's delayed, noisy true pose."""

    kind = "sim"

    def __init__(self, fleet: SimFleet) -> None:
        self.fleet = fleet
        self.drone_ids = list(fleet.names)
        self._last_t = dict.fromkeys(self.drone_ids, -np.inf)

    def read(self, now: float) -> dict[str, BodySample | None]:
        """The fleet's mocap samples that are newer than the ones already returned."""
        out: dict[str, BodySample | None] = {}
        for i, d in enumerate(self.drone_ids):
            s = self.fleet.mocap(i)
            if s.t > self._last_t[d]:
                self._last_t[d] = s.t
                out[d] = BodySample(s.t, s.p, s.q, s.v)
            else:
                out[d] = None
        return out

    def close(self) -> None:
        """Stop the simulator and close its sockets."""
        self.fleet.close()


@dataclass
class _Body:
    frame: int
    t: float
    p: Array
    q: Array
    v: Array


class MotionCaptureSource:
    """Real motion capture via ``motioncapture`` on a background thread.

    Args:
        mocap_type: one of :data:`MOCAP_TYPES`.
        body_map: rigid-body name → drone id.
        clock: stamps frames with simulation (here: real) time.
        host: the mocap server (``hostname`` option), unused for ``mock``.
        options: extra libmotioncapture options, e.g. for ``mock``
            ``{"rigid_bodies": "cf1(0,0,1,1,0,0,0)"}``: name(x,y,z,qw,qx,qy,qz), ``;``-separated
            (w first, as libmotioncapture's factory parses it), and ``frequency`` [Hz].
        connect_timeout_s: how long to wait for the connection before :class:`MocapError`.
        velocity_alpha: low-pass weight of the newest finite-difference velocity (0..1].
        module: the ``motioncapture`` module (tests may pass a fake).
    """

    kind = "motioncapture"

    def __init__(self, mocap_type: str, body_map: dict[str, str], clock: Clock,
                 host: str | None = None, options: dict[str, str] | None = None,
                 connect_timeout_s: float = 5.0, velocity_alpha: float = 0.5,
                 module: Any = None) -> None:
        if mocap_type not in MOCAP_TYPES:
            raise MocapError(f"unknown mocap type {mocap_type!r}; expected one of "
                             f"{', '.join(MOCAP_TYPES)}")
        if mocap_type != "mock" and not host:
            raise MocapError(f"--mocap-host is required for {mocap_type}")
        self.module = import_motioncapture() if module is None else module
        self.clock = clock
        self.body_map = dict(body_map)
        self.drone_ids = list(dict.fromkeys(body_map.values()))
        self.alpha = velocity_alpha
        cfg = dict(options or {})
        if host:
            cfg.setdefault("hostname", host)
        self._lock = threading.Lock()
        self._bodies: dict[str, _Body] = {}
        self._returned: dict[str, int] = {}
        self._frame = 0
        self.frames = 0
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._error: str | None = None
        self._thread = threading.Thread(target=self._run, args=(mocap_type, cfg),
                                        name="mocap", daemon=True)
        self._thread.start()
        if not self._ready.wait(connect_timeout_s):
            self._stop.set()
            # A blocked connect cannot be interrupted; the daemon thread is left behind.
            raise MocapError(f"no connection to {mocap_type} at {host} within "
                             f"{connect_timeout_s:g} s")
        if self._error is not None:
            self._thread.join(1.0)
            raise MocapError(self._error)

    def _run(self, mocap_type: str, cfg: dict[str, str]) -> None:
        try:
            mc = self.module.connect(mocap_type, cfg)
        except Exception as e:  # the binding raises plain RuntimeError
            self._error = f"cannot connect to {mocap_type}: {e}"
            self._ready.set()
            return
        self._ready.set()
        while not self._stop.is_set():
            try:
                mc.waitForNextFrame()
                bodies = mc.rigidBodies
            except Exception as e:
                _log.error("mocap frame failed: %s", e)
                self._stop.wait(0.1)
                continue
            self._ingest(self.clock.now(), bodies)

    def _ingest(self, now: float, bodies: dict[str, Any]) -> None:
        with self._lock:
            self._frame += 1
            self.frames += 1
            for name, rb in bodies.items():
                if name not in self.body_map:
                    continue
                p = np.array(rb.position, dtype=np.float64).reshape(3)
                r = rb.rotation
                try:
                    q = quat_normalize([r.w, r.x, r.y, r.z])
                except ValueError:
                    continue
                if not np.all(np.isfinite(p)):
                    continue
                prev = self._bodies.get(name)
                v = np.zeros(3)
                if prev is not None and now > prev.t:
                    raw = (p - prev.p) / (now - prev.t)
                    v = self.alpha * raw + (1.0 - self.alpha) * prev.v
                self._bodies[name] = _Body(self._frame, now, p, q, v)

    def read(self, now: float) -> dict[str, BodySample | None]:
        """Bodies of frames not yet returned (a body absent from a frame is not repeated)."""
        out: dict[str, BodySample | None] = dict.fromkeys(self.drone_ids)
        with self._lock:
            for name, drone in self.body_map.items():
                b = self._bodies.get(name)
                if b is None or self._returned.get(name) == b.frame:
                    continue
                self._returned[name] = b.frame
                out[drone] = BodySample(b.t, b.p.copy(), b.q.copy(), b.v.copy())
        return out

    def close(self) -> None:
        """Stop and join the frame thread."""
        self._stop.set()
        self._thread.join(2.0)


class Health:
    """Per-drone mocap health: ``missing`` (never seen), ``stale`` (older than ``stale_s``),
    ``ok`` (``unknown`` before the first update). ``update`` returns the drones whose state
    changed and calls ``report(drone, state, age)`` for each."""

    def __init__(self, drone_ids: list[str], stale_s: float,
                 report: Callable[[str, str, float], None] | None = None) -> None:
        self.stale_s = stale_s
        self.last: dict[str, float | None] = dict.fromkeys(drone_ids)
        self.state: dict[str, str] = dict.fromkeys(drone_ids, "unknown")
        self.report = report

    def seen(self, drone: str, t: float) -> None:
        """A fresh sample of ``drone`` captured at t [s]."""
        self.last[drone] = t

    def age(self, drone: str, now: float) -> float:
        """Seconds since the last fresh sample (inf if never)."""
        t = self.last[drone]
        return np.inf if t is None else max(0.0, now - t)

    def update(self, now: float) -> list[str]:
        """Recompute every state at time ``now``; return the drones that changed."""
        changed = []
        for d, t in self.last.items():
            new = "missing" if t is None else ("stale" if now - t > self.stale_s else "ok")
            if new != self.state[d]:
                self.state[d] = new
                changed.append(d)
                if self.report is not None:
                    self.report(d, new, self.age(d, now))
        return changed


def wall_sleep_until(deadline: float) -> None:
    """Sleep until the monotonic time ``deadline``."""
    rest = deadline - time.monotonic()
    if rest > 0:
        time.sleep(rest)
