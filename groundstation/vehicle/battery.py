"""What the simulated autopilot makes of its battery: readings, warnings and failsafes.

The physics (charge drawn, current ∝ thrust^1.5, LiPo voltage curve) is
:mod:`groundstation.vehicle.dynamics`'s. Per flavour (chosen by :mod:`groundstation.vehicle.
flavours`; sources read with the ``search`` tool):

* ArduPilot (libraries/AP_BattMonitor/AP_BattMonitor_Params.cpp; ArduCopter/events.cpp).
  Remaining [%] is coulomb counting against BATT_CAPACITY [mAh] (the simulator sets it to
  the pack's capacity, as a configured vehicle has it). Low failsafe: the raw pack voltage
  (BATT_FS_VOLTSRC 0) below BATT_LOW_VOLT [V] continuously for BATT_LOW_TIMER [s], or the
  remaining capacity below BATT_LOW_MAH [mAh] (0: off); critical likewise with
  BATT_CRT_VOLT / BATT_CRT_MAH. Each level fires once (low, then critical) and only while
  armed; its action is BATT_FS_LOW_ACT / BATT_FS_CRT_ACT: 0 none, 1 Land, 2 RTL, 3 SmartRTL
  or RTL, 4 SmartRTL or Land, 5 Terminate, 6 DO_LAND_START or RTL (SmartRTL and DO_LAND_START
  are not simulated: 3 and 6 act as RTL, 4 as Land). BATTERY_STATUS.charge_state is OK, LOW
  or CRITICAL by the failsafe level reached.
* PX4 (src/modules/commander/commander_params.c, battery params BAT_*_THR). Remaining is
  coulomb counting when BAT1_CAPACITY [mAh] > 0, else voltage based: the load-compensated
  cell voltage between BAT1_V_EMPTY and BAT1_V_CHARGED [V] (this simulator compensates
  exactly: it uses the open-circuit voltage). Levels: below BAT_LOW_THR LOW (warning only),
  BAT_CRIT_THR CRITICAL, BAT_EMERGEN_THR EMERGENCY. COM_LOW_BAT_ACT: 0 warning, 2 Land at
  critical, 3 Return at critical and Land at emergency (through COM_FAIL_ACT_T, see
  :mod:`groundstation.vehicle.failsafe`).

Warnings are STATUSTEXT lines (this simulator's wording).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from agent.wire.mavlink import mavlink as mav
from groundstation.vehicle import failsafe
from groundstation.vehicle.dynamics import (
    BATTERY_R_OHM,
    IDLE_CURRENT_A,
    THRUST_CURRENT_A,
    cell_ocv,
)

Params = Mapping[str, float]
#: Period of this simulator's battery failsafe check [s].
CHECK_S = 0.1
#: BATT_FS_*_ACT (ArduCopter) → failsafe action.
AP_ACTIONS = {1: "land", 2: "rtl", 3: "rtl", 4: "land", 5: "terminate", 6: "rtl"}
OK, LOW, CRITICAL, EMERGENCY = (int(mav.MAV_BATTERY_CHARGE_STATE_OK),
                                int(mav.MAV_BATTERY_CHARGE_STATE_LOW),
                                int(mav.MAV_BATTERY_CHARGE_STATE_CRITICAL),
                                int(mav.MAV_BATTERY_CHARGE_STATE_EMERGENCY))


@dataclass
class Reading:
    """One battery reading: voltage [V], current [A], consumed [mAh], remaining (0..1, None
    unknown), MAV_BATTERY_CHARGE_STATE and the true state of charge (0..1, physics)."""

    voltage: float
    current: float
    consumed: float
    remaining: float | None
    charge_state: int
    soc: float


class BatteryMonitor:
    """One autopilot's battery monitor and failsafe (module docstring)."""

    def __init__(self, ap: Any) -> None:
        self.ap = ap
        self.level = OK  #: highest level reached (MAV_BATTERY_CHARGE_STATE)
        self._low_since: float | None = None
        self._crit_since: float | None = None
        self._next = 0.0

    def read(self) -> Reading:
        """The current reading (module docstring)."""
        ap, p = self.ap, self.ap.params
        st = ap.truth()
        thrust = min(max(float(st.thrust[ap.i]), 0.0), 1.0)  # dynamics.battery_current, one
        amps = IDLE_CURRENT_A + (THRUST_CURRENT_A * thrust**1.5 if st.armed[ap.i] else 0.0)
        used = float(st.consumed[ap.i])
        soc = min(max(1.0 - used / p.battery_mah, 0.0), 1.0)
        volt = p.battery_cells * float(cell_ocv(soc)) - BATTERY_R_OHM * amps
        rem = ap.flavour.battery_remaining(ap.params_table, used, soc)
        if rem is not None:
            rem = min(max(rem, 0.0), 1.0)
        return Reading(volt, amps, used, rem, self.level, soc)

    def update(self, t: float) -> None:
        """Check the failsafe levels (10 Hz) at simulation time t [s] and act (armed only)."""
        if t < self._next:
            return
        self._next = t + CHECK_S
        r = self.read()
        new = self.ap.flavour.battery_level(self, r, t)
        if new <= self.level:
            return
        self.level = new
        self._announce(r, new)
        if not self.ap.armed:
            return
        action = self.ap.flavour.battery_action(self.ap.params_table, new)
        if action is not None:
            failsafe.act(self.ap, action, t, "battery")

    # -- ArduPilot ----------------------------------------------------------------------
    def ardupilot_level(self, r: Reading, t: float) -> int:
        """ArduPilot's level: low / critical voltage held BATT_LOW_TIMER, or mAh left."""
        pt = self.ap.params_table
        timer = float(pt["BATT_LOW_TIMER"])
        cap = float(pt["BATT_CAPACITY"])
        left = cap - r.consumed
        self._crit_since = _since(self._crit_since, r.voltage < float(pt["BATT_CRT_VOLT"]), t)
        self._low_since = _since(self._low_since, r.voltage < float(pt["BATT_LOW_VOLT"]), t)
        crit_mah, low_mah = float(pt["BATT_CRT_MAH"]), float(pt["BATT_LOW_MAH"])
        if (self._crit_since is not None and timer > 0 and t - self._crit_since >= timer) or \
                (crit_mah > 0 and left < crit_mah):
            return CRITICAL
        if (self._low_since is not None and timer > 0 and t - self._low_since >= timer) or \
                (low_mah > 0 and left < low_mah):
            return LOW
        return self.level

    # -- PX4 ----------------------------------------------------------------------------
    def px4_level(self, r: Reading) -> int:
        """PX4's level: the remaining charge below BAT_LOW_THR / _CRIT_ / _EMERGEN_."""
        if r.remaining is None:
            return self.level
        pt = self.ap.params_table
        if r.remaining < float(pt["BAT_EMERGEN_THR"]):
            return EMERGENCY
        if r.remaining < float(pt["BAT_CRIT_THR"]):
            return CRITICAL
        if r.remaining < float(pt["BAT_LOW_THR"]):
            return LOW
        return self.level

    def _announce(self, r: Reading, level: int) -> None:
        word = {LOW: "low", CRITICAL: "critical", EMERGENCY: "emergency"}.get(level, "ok")
        sev = mav.MAV_SEVERITY_WARNING if level == LOW else mav.MAV_SEVERITY_CRITICAL
        failsafe.statustext(self.ap, sev, f"Battery 1 is {word} {r.voltage:.2f}V used "
                                          f"{r.consumed:.0f} mAh")


def ardupilot_remaining(pt: Params, used: float) -> float | None:
    """ArduPilot's remaining charge: coulomb counting against BATT_CAPACITY (None: 0)."""
    cap = float(pt["BATT_CAPACITY"])
    return 1.0 - used / cap if cap > 0 else None


def px4_remaining(pt: Params, used: float, soc: float) -> float | None:
    """PX4's: coulomb counting against BAT1_CAPACITY when set, else the open-circuit cell
    voltage of ``soc`` between BAT1_V_EMPTY and BAT1_V_CHARGED."""
    cap = float(pt["BAT1_CAPACITY"])
    if cap > 0:
        return 1.0 - used / cap
    empty, full = float(pt["BAT1_V_EMPTY"]), float(pt["BAT1_V_CHARGED"])
    return (float(cell_ocv(soc)) - empty) / (full - empty) if full > empty else None


def ardupilot_action(pt: Params, level: int) -> str | None:
    """BATT_FS_CRT_ACT / BATT_FS_LOW_ACT of the new level."""
    name = "BATT_FS_CRT_ACT" if level == CRITICAL else "BATT_FS_LOW_ACT"
    return AP_ACTIONS.get(int(pt[name]))


def px4_action(pt: Params, level: int) -> str | None:
    """COM_LOW_BAT_ACT at the new level (a warning at LOW)."""
    act = int(pt["COM_LOW_BAT_ACT"])
    if level == LOW:
        return "warn"
    if act == 2:
        return "land"
    if act == 3:
        return "rtl" if level == CRITICAL else "land"
    return "warn"


def _since(since: float | None, below: bool, t: float) -> float | None:
    """When a condition started holding (None: it does not hold now)."""
    if not below:
        return None
    return t if since is None else since

