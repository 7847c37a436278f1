"""The simulated EKF outdoors: the true state plus a GNSS-like error model (seeded).

Which source the EKF fuses follows the autopilot's own parameters (:func:`position_source`,
chosen per flavour by :mod:`groundstation.vehicle.flavours`):
ArduPilot's EK3_SRC1_POSXY (3 GPS, 6 external navigation; libraries/AP_NavEKF/
AP_NavEKF_Source.cpp) and PX4's EKF2_EV_CTRL bit 0 / EKF2_GPS_CTRL bit 0 (src/modules/ekf2/
params_*.yaml). GNSS is there only if the vehicle carries a receiver
(``VehicleParams.gnss``: "rtk" or "3d"); external navigation only while vision/odometry
arrives (within 1 s). With external navigation the estimate is the true state plus
``sensor_noise_pos`` / ``sensor_noise_att`` (the mocap-forwarding case); with GNSS it is

    p̂ = p + d(t) + w_p,   v̂ = v + w_v,   att̂ = att + w_att,

where d(t) is a first-order Gauss-Markov drift per axis (stationary 1σ ``drift_h`` /
``drift_v`` [m], correlation time ``drift_tau`` [s]) stepped on a fixed 0.1 s grid of
simulation time with its own random stream, so its realisation depends only on the seed and
time, not on how often the estimate is read; w are white Gaussian (1σ ``pos_noise_h`` /
``pos_noise_v`` [m], ``vel_noise`` [m/s], ``att_noise`` roll/pitch and ``yaw_noise`` [rad]).
The receiver itself (GPS_RAW_INT) reports p + d(t) + w_gps (``gps_noise_h`` / ``_v`` [m]):
EKF and receiver share the slowly varying error, as they do on a real vehicle.

Magnitudes (1σ) of the presets, chosen from typical receiver specifications (RTK fixed: about
1 cm + 1 ppm horizontal; single-frequency 3-D fix: metres):

=========  =======  =====  =========  =====  =====  ====  ======  ======  =====  ====  ====
preset     fix      pos_h  pos_v      drift  drift  tau   vel     att     yaw    gps   gps
                    [m]    [m]        h [m]  v [m]  [s]   [m/s]   [rad]   [rad]  h     v
=========  =======  =====  =========  =====  =====  ====  ======  ======  =====  ====  ====
rtk        6 RTK    0.01   0.015      0.02   0.03   60    0.02    0.002   0.005  0.01  0.02
3d         3 3D     0.3    0.5        1.0    1.5    120   0.1     0.004   0.01   0.5   0.8
=========  =======  =====  =========  =====  =====  ====  ======  ======  =====  ====  ====

``VehicleParams.gnss_noise`` overrides any field by name (e.g. ``{"drift_h": 0.0}``).
Frames: positions [m; local NED from the EKF origin], velocities [m/s; NED], attitude
roll, pitch, yaw [rad; NED→FRD].
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agent.wire.mavlink import mavlink as mav

Array = NDArray[np.float64]

#: The drift's time grid [s sim].
DRIFT_STEP = 0.1


@dataclass(frozen=True)
class GnssModel:
    """Error magnitudes of the GNSS-aided EKF (module docstring; 1σ, units in the table)."""

    fix_type: int = mav.GPS_FIX_TYPE_RTK_FIXED
    pos_noise_h: float = 0.01
    pos_noise_v: float = 0.015
    drift_h: float = 0.02
    drift_v: float = 0.03
    drift_tau: float = 60.0
    vel_noise: float = 0.02
    att_noise: float = 0.002
    yaw_noise: float = 0.005
    gps_noise_h: float = 0.01
    gps_noise_v: float = 0.02
    satellites: int = 24
    hdop: float = 0.7
    vdop: float = 1.1

    @classmethod
    def preset(cls, name: str, overrides: dict[str, float] | None = None) -> GnssModel:
        """The ``rtk`` or ``3d`` preset with ``overrides`` (field name → value)."""
        if name == "rtk":
            model = cls()
        elif name == "3d":
            model = cls(mav.GPS_FIX_TYPE_3D_FIX, 0.3, 0.5, 1.0, 1.5, 120.0, 0.1, 0.004, 0.01,
                        0.5, 0.8, 12, 1.2, 1.8)
        else:
            raise ValueError(f"gnss must be 'rtk' or '3d', got {name!r}")
        known = {f.name for f in fields(cls)}
        bad = set(overrides or {}) - known
        if bad:
            raise ValueError(f"unknown gnss_noise field(s) {sorted(bad)}")
        kw: dict[str, Any] = {k: (int(v) if k in ("fix_type", "satellites") else float(v))
                              for k, v in (overrides or {}).items()}
        model = replace(model, **kw)
        if not (model.drift_tau > 0 and min(model.pos_noise_h, model.pos_noise_v, model.drift_h,
                                            model.drift_v, model.vel_noise, model.att_noise,
                                            model.yaw_noise, model.gps_noise_h,
                                            model.gps_noise_v) >= 0):
            raise ValueError("gnss noise magnitudes must be >= 0 and drift_tau > 0")
        return model

    @property
    def h_acc(self) -> float:
        """Receiver horizontal accuracy [m] (1σ of drift and white noise together)."""
        return math.hypot(self.drift_h, self.gps_noise_h)

    @property
    def v_acc(self) -> float:
        """Receiver vertical accuracy [m]."""
        return math.hypot(self.drift_v, self.gps_noise_v)


class GnssEkf:
    """One vehicle's GNSS error processes (module docstring). ``seed`` fixes both streams."""

    def __init__(self, model: GnssModel, seed: tuple[int, ...]) -> None:
        self.model = model
        self._drift_rng = np.random.default_rng([*seed, 10])
        self._white_rng = np.random.default_rng([*seed, 11])
        self._sigma = np.array([model.drift_h, model.drift_h, model.drift_v])
        # Start in the stationary distribution, as a receiver that has been on a while.
        self._drift = self._sigma * self._drift_rng.standard_normal(3)
        self._k = 0  #: grid index of _drift

    def drift(self, t: float) -> Array:
        """Gauss-Markov drift d(t) [m; NED] at simulation time t (held between grid points;
        exact discretisation x_{k+1} = a x_k + σ √(1 − a²) w_k, a = exp(−Δ/τ))."""
        k = max(math.floor(t / DRIFT_STEP), 0)
        n = k - self._k
        if n > 0:
            a = math.exp(-DRIFT_STEP / self.model.drift_tau)
            w = self._drift_rng.standard_normal((n, 3)) * (self._sigma * math.sqrt(1.0 - a * a))
            powers = a ** np.arange(n - 1, -1, -1, dtype=np.float64)  # a^(n-1-j)
            self._drift = a**n * self._drift + powers @ w
            self._k = k
        return self._drift.copy()

    def estimate(self, t: float, p: Array, v: Array, att: Array) -> tuple[Array, Array, Array]:
        """(p̂ [m; NED], v̂ [m/s; NED], att̂ [rad]) of the true p, v, att at time t."""
        m, rng = self.model, self._white_rng
        w = rng.standard_normal(9)
        p_hat = p + self.drift(t) + w[0:3] * np.array([m.pos_noise_h, m.pos_noise_h,
                                                        m.pos_noise_v])
        v_hat = v + w[3:6] * m.vel_noise
        att_hat = att + w[6:9] * np.array([m.att_noise, m.att_noise, m.yaw_noise])
        return p_hat, v_hat, att_hat

    def receiver(self, t: float, p: Array) -> Array:
        """The receiver's position [m; NED] of the true p at time t (GPS_RAW_INT)."""
        m = self.model
        w = self._white_rng.standard_normal(3)
        return p + self.drift(t) + w * np.array([m.gps_noise_h, m.gps_noise_h, m.gps_noise_v],
                                                dtype=np.float64)


def ardupilot_sources(params: Mapping[str, float]) -> tuple[bool, bool]:
    """(external navigation, GNSS) selected by ArduPilot's parameters (``params``: name →
    value): VISO_TYPE > 0 with EK3_SRC1_POSXY = 6; EK3_SRC1_POSXY = 3."""
    src = int(params.get("EK3_SRC1_POSXY", 3))
    return float(params.get("VISO_TYPE", 0)) > 0 and src == 6, src == 3


def px4_sources(params: Mapping[str, float]) -> tuple[bool, bool]:
    """(external navigation, GNSS) selected by PX4's: EKF2_EV_CTRL bit 0, EKF2_GPS_CTRL bit 0."""
    return (int(params.get("EKF2_EV_CTRL", 0)) & 1 == 1,
            int(params.get("EKF2_GPS_CTRL", 7)) & 1 == 1)


def position_source(sources: tuple[bool, bool], gnss: bool, vision_fresh: bool) -> str | None:
    """What the EKF's position comes from: "vision", "gnss" or None (no position).

    ``sources`` are the (external navigation, GNSS) sources the autopilot's parameters select
    (:func:`ardupilot_sources`, :func:`px4_sources`). External navigation wins when it is
    configured and fresh (the indoor set-up); GNSS needs a receiver and the source selected."""
    ev, gps = sources
    if ev and vision_fresh:
        return "vision"
    if gps and gnss:
        return "gnss"
    return None
