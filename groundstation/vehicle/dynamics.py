"""Pure, vectorised quadrotor dynamics of the simulated fleet (no I/O, no clocks, no threads).

World frame NED, body frame FRD, attitude as ZYX Euler angles (roll, pitch, yaw) [rad].
Translational rigid-body dynamics

    m v̇ = −T z_B + m g ẑ − k_drag (v − w),   T = T_max · thrust,   T_max = m g / hover_thrust

with w the air velocity (steady wind plus a seeded Ornstein-Uhlenbeck gust per vehicle), a
first-order response of roll, pitch and yaw to the commanded attitude (time constant
``tau_att``) and of the thrust to the commanded thrust (motor lag ``tau_thrust``), ground
contact at z = 0 (no penetration, no sliding) and a battery that drains with the thrust.

Battery model (per vehicle): charge drawn q [mAh] integrates the current
I = IDLE_CURRENT_A + THRUST_CURRENT_A · thrust^1.5 [A] while armed (idle electronics only
when disarmed; hover power grows as thrust^1.5 by momentum theory, so the current at
constant voltage does too); state of charge soc = 1 − q / battery_mah; terminal voltage
V = cells · OCV(soc) − I · BATTERY_R_OHM [V], with the LiPo open-circuit cell curve
:data:`OCV_SOC` / :data:`OCV_V` (piecewise linear, 3.27 V empty … 4.20 V full, the usual
shape: steep at both ends, flat around 3.8 V). What each autopilot makes of it (remaining
percentage, failsafes): :mod:`groundstation.vehicle.battery`.

:func:`step` maps (state, command, params, dt[, gust noise]) to the next state; the caller
owns time and randomness (the Crazyswarm2 style of a pure vehicle model).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from groundstation.vehicle.params import VehicleParams

Array = NDArray[np.float64]

#: LiPo cell voltage [V] when full and when empty.
CELL_FULL_V, CELL_EMPTY_V = 4.2, 3.27
#: Open-circuit LiPo cell voltage [V] (OCV_V) at each state of charge (OCV_SOC, 0..1).
OCV_SOC = np.array([0.0, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0])
OCV_V = np.array([3.27, 3.61, 3.69, 3.73, 3.77, 3.79, 3.82, 3.87, 3.92, 3.97, 4.06, 4.20])
#: Battery current [A] = idle + per_thrust · thrust^1.5 (armed), and internal resistance [Ω].
IDLE_CURRENT_A, THRUST_CURRENT_A, BATTERY_R_OHM = 0.5, 30.0, 0.02


@dataclass
class VehicleState:
    """State of n vehicles.

    p, v: (n, 3) position [m; world NED] and velocity [m/s; world NED];
    att: (n, 3) roll, pitch, yaw [rad; NED→FRD, ZYX]; rates: (n, 3) Euler angle rates [rad/s];
    thrust: (n,) normalised thrust after the motor lag (0..1); gust: (n, 3) gust velocity
    [m/s; world NED]; consumed: (n,) battery charge drawn [mAh]; armed: (n,) motors enabled.
    """

    p: Array
    v: Array
    att: Array
    rates: Array
    thrust: Array
    gust: Array
    consumed: Array
    armed: NDArray[np.bool_]

    @property
    def n(self) -> int:
        """Number of vehicles."""
        return int(self.p.shape[0])

    def copy(self) -> VehicleState:
        """A deep copy."""
        return VehicleState(self.p.copy(), self.v.copy(), self.att.copy(), self.rates.copy(),
                            self.thrust.copy(), self.gust.copy(), self.consumed.copy(),
                            self.armed.copy())


@dataclass(frozen=True)
class FleetParams:
    """Per-vehicle physical parameters as (n,) arrays: mass [kg], T_max [N], drag [N s/m],
    tau_att / tau_thrust / gust_tau [s], gust_std [m/s], wind (n, 3) [m/s; world NED],
    battery capacity [mAh] and cell count; g [m/s²]."""

    mass: Array
    max_thrust: Array
    drag: Array
    tau_att: Array
    tau_thrust: Array
    wind: Array
    gust_std: Array
    gust_tau: Array
    battery_mah: Array
    cells: Array
    g: float

    @classmethod
    def of(cls, params: Sequence[VehicleParams]) -> FleetParams:
        """Stack one :class:`VehicleParams` per vehicle."""
        def col(name: str) -> Array:
            return np.array([float(getattr(p, name)) for p in params])

        return cls(col("mass"), np.array([p.max_thrust for p in params]), col("drag"),
                   col("tau_att"), col("tau_thrust"),
                   np.array([p.wind for p in params], dtype=np.float64).reshape(-1, 3),
                   col("gust_std"), col("gust_tau"), col("battery_mah"),
                   col("battery_cells"), float(params[0].g))


def initial_state(p_ned: Array, yaw_ned: Array | None = None) -> VehicleState:
    """Vehicles at rest, disarmed, full battery: positions (n, 3) [m; world NED], headings
    (n,) [rad; NED]."""
    p = np.array(p_ned, dtype=np.float64).reshape(-1, 3)
    n = p.shape[0]
    att = np.zeros((n, 3))
    if yaw_ned is not None:
        att[:, 2] = wrap_angle(np.asarray(yaw_ned, dtype=np.float64))
    return VehicleState(p, np.zeros((n, 3)), att, np.zeros((n, 3)), np.zeros(n),
                        np.zeros((n, 3)), np.zeros(n), np.zeros(n, dtype=bool))


def wrap_angle(a: Array) -> Array:
    """Angles wrapped to [−π, π) [rad]."""
    return np.asarray((a + np.pi) % (2 * np.pi) - np.pi, dtype=np.float64)


def body_z_axes(att: Array) -> Array:
    """Body z axis (down, FRD) of each attitude, in world NED coordinates: (n, 3)."""
    r, pch, y = att[:, 0], att[:, 1], att[:, 2]
    cr, sr, cp, sp = np.cos(r), np.sin(r), np.cos(pch), np.sin(pch)
    cy, sy = np.cos(y), np.sin(y)
    return np.stack([cy * sp * cr + sy * sr, sy * sp * cr - cy * sr, cp * cr], axis=1)


def on_ground(state: VehicleState) -> NDArray[np.bool_]:
    """Which vehicles rest on the ground (z ≥ −1 mm NED and not climbing)."""
    return np.asarray((state.p[:, 2] >= -1e-3) & (state.v[:, 2] >= -1e-3))


def battery_current(state: VehicleState) -> Array:
    """Battery current [A] per vehicle: idle electronics plus motors (armed only)."""
    motors = THRUST_CURRENT_A * np.clip(state.thrust, 0.0, 1.0) ** 1.5
    return IDLE_CURRENT_A + np.where(state.armed, motors, 0.0)


def battery_remaining(state: VehicleState, params: FleetParams) -> Array:
    """State of charge (0..1) per vehicle."""
    return np.clip(1.0 - state.consumed / params.battery_mah, 0.0, 1.0)


def cell_ocv(soc: Array | float) -> Array:
    """Open-circuit cell voltage [V] at state(s) of charge ``soc`` (0..1, clipped)."""
    return np.asarray(np.interp(np.clip(soc, 0.0, 1.0), OCV_SOC, OCV_V), dtype=np.float64)


def battery_voltage(state: VehicleState, params: FleetParams) -> Array:
    """Terminal voltage [V]: cells × OCV(soc) − I R (module docstring)."""
    soc = battery_remaining(state, params)
    ocv = params.cells * cell_ocv(soc)
    return np.asarray(ocv - BATTERY_R_OHM * battery_current(state), dtype=np.float64)


def step(state: VehicleState, command: Array, params: FleetParams, dt: float,
         gust_noise: Array | None = None) -> VehicleState:
    """The fleet after ``dt`` [s] under ``command`` (n, 4): roll, pitch, yaw [rad; NED] and
    normalised thrust 0..1 (ignored, i.e. 0, for disarmed vehicles).

    ``gust_noise`` (n, 3): standard normal draws for the gust process (None: no new gust).
    Returns a new state; ``state`` is not modified.
    """
    cmd_thrust = np.where(state.armed, np.clip(command[:, 3], 0.0, 1.0), 0.0)
    a_att = 1.0 - np.exp(-dt / params.tau_att)
    a_thr = 1.0 - np.exp(-dt / params.tau_thrust)
    att = state.att.copy()
    d_yaw = wrap_angle(command[:, 2] - att[:, 2])
    att[:, 0:2] += (command[:, 0:2] - att[:, 0:2]) * a_att[:, None]
    att[:, 2] = wrap_angle(att[:, 2] + d_yaw * a_att)
    d = att - state.att
    d[:, 2] = wrap_angle(d[:, 2])
    thrust = state.thrust + (cmd_thrust - state.thrust) * a_thr
    gust = state.gust
    if gust_noise is not None:  # Ornstein-Uhlenbeck: exact discretisation
        decay = np.exp(-dt / params.gust_tau)
        gust = gust * decay[:, None] + (params.gust_std * np.sqrt(1.0 - decay**2))[:, None] \
            * gust_noise
    air = params.wind + gust
    force = -(params.max_thrust * thrust)[:, None] * body_z_axes(att) \
        - params.drag[:, None] * (state.v - air)
    acc = force / params.mass[:, None]
    acc[:, 2] += params.g
    v = state.v + acc * dt
    p = state.p + v * dt
    below = p[:, 2] >= 0.0
    if below.any():  # ground contact: no penetration, no sliding
        p[below, 2] = 0.0
        v[below] = np.where(v[below, 2:3] > 0.0, 0.0, v[below])
        v[below, 0:2] = 0.0
    new = replace(state, p=p, v=v, att=att, rates=d / dt, thrust=thrust, gust=gust)
    new.consumed = state.consumed + battery_current(new) * dt / 3.6  # A·s → mAh
    return new
