"""The vehicle's battery as a typed state: remaining charge, pack voltage, current, from
BATTERY_STATUS (preferred) and SYS_STATUS, for the runtime's hand-over decision and for
``viscover status`` (:meth:`BatteryState.published`, in the agent's published state).

MAVLink units and "unknown" markers (common.xml):

* BATTERY_STATUS: ``voltages[10]`` cell voltages [mV], UINT16_MAX = not a cell (if cells are
  not measured, cell 0 holds the pack voltage; a pack above 65534 mV continues in cell 1);
  ``voltages_ext[4]`` cells 11-14 [mV], 0 = not used; ``current_battery`` [cA], −1 unknown;
  ``current_consumed`` [mAh], −1 unknown; ``battery_remaining`` [%], −1 unknown;
  ``time_remaining`` [s], 0 unknown; ``charge_state`` MAV_BATTERY_CHARGE_STATE (0 unknown).
* SYS_STATUS: ``voltage_battery`` [mV], UINT16_MAX unknown; ``current_battery`` [cA], −1
  unknown; ``battery_remaining`` [%], −1 unknown.

A BATTERY_STATUS of the battery ``battery_id`` (0: the first) newer than ``prefer_s`` [s
wall] wins; SYS_STATUS fills in what it lacks. Values out of range (a remaining charge
above 100 %, a negative voltage, NaN) are dropped and counted, never raised.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import asdict, dataclass, replace
from typing import Any

from agent.flight.link import VehicleLink
from agent.wire.peer import Battery

UINT16_MAX = 65535


@dataclass(frozen=True)
class BatteryState:
    """What the vehicle says of its battery: remaining charge [%], pack voltage [V], current
    [A] (positive = discharging), charge consumed [mAh], the autopilot's remaining-time
    estimate [s], MAV_BATTERY_CHARGE_STATE, the source message(s), and when it was heard
    ``t`` [s mission]. None = not reported."""

    remaining_pct: float | None = None
    voltage_v: float | None = None
    current_a: float | None = None
    consumed_mah: float | None = None
    time_remaining_s: float | None = None
    charge_state: int | None = None
    source: str = ""
    t: float = -math.inf

    def summary(self) -> str:
        """One line for ``viscover status``, e.g. '74 %, 15.31 V, 12.0 A'."""
        parts = [f"{self.remaining_pct:.0f} %" if self.remaining_pct is not None else "? %"]
        if self.voltage_v is not None:
            parts.append(f"{self.voltage_v:.2f} V")
        if self.current_a is not None:
            parts.append(f"{self.current_a:.1f} A")
        return ", ".join(parts)

    def published(self) -> Battery:
        """What the agent publishes of it (its state's ``battery``: charge and voltage)."""
        return Battery(pct=self.remaining_pct, voltage_v=self.voltage_v)

    def endurance_s(self, capacity_mah: float | None = None) -> float | None:
        """Flight time left [s]: the autopilot's own estimate, else the remaining charge of
        a ``capacity_mah`` pack at the present current; None when neither is known."""
        if self.time_remaining_s is not None and self.time_remaining_s > 0:
            return self.time_remaining_s
        if capacity_mah and self.remaining_pct is not None and self.current_a \
                and self.current_a > 0:
            return capacity_mah * self.remaining_pct / 100.0 / (self.current_a * 1000.0) * 3600.0
        return None

    def to_dict(self) -> dict[str, Any]:
        """Plain data (for a journal or a status message); -inf time as None."""
        d = asdict(self)
        d["t"] = None if math.isinf(self.t) else self.t
        return d


def hand_over_needed(battery: BatteryState, needed_s: float, reserve_frac: float = 0.2,
                     capacity_mah: float | None = None, floor_pct: float = 30.0) -> bool:
    """Whether a drone should hand its remaining work over now: its endurance
    (:meth:`BatteryState.endurance_s`) cannot cover ``needed_s`` [s] (the remaining work and
    the flight home) with a ``reserve_frac`` margin; without an endurance estimate, when the
    remaining charge is at or below ``floor_pct`` [%]. Unknown battery: False."""
    endurance = battery.endurance_s(capacity_mah)
    if endurance is not None:
        return endurance * (1.0 - reserve_frac) < needed_s
    return battery.remaining_pct is not None and battery.remaining_pct <= floor_pct


def _pack_voltage_mv(cells: list[int], ext: list[int]) -> float | None:
    """Pack voltage [mV] of BATTERY_STATUS cells (the sum of the valid ones)."""
    valid = [c for c in cells if c != UINT16_MAX] + [c for c in ext if 0 < c < UINT16_MAX]
    return float(sum(valid)) if valid else None


class BatteryReader:
    """The latest :class:`BatteryState` of the vehicle behind ``link`` (thread-safe)."""

    def __init__(self, link: VehicleLink, battery_id: int = 0, prefer_s: float = 5.0) -> None:
        self.link = link
        self.battery_id = battery_id
        self.prefer_s = prefer_s
        self.rejected = 0  #: messages with out-of-range values
        self._lock = threading.Lock()
        self._sys = BatteryState()
        self._bat = BatteryState()
        self._bat_wall = -math.inf
        self._unsub = link.subscribe(("BATTERY_STATUS", "SYS_STATUS"), self._on_message)

    def close(self) -> None:
        """Stop listening."""
        self._unsub()

    @property
    def state(self) -> BatteryState:
        """BATTERY_STATUS (if fresh) with SYS_STATUS filling its gaps."""
        with self._lock:
            sys_s, bat = self._sys, self._bat
            if time.monotonic() - self._bat_wall > self.link.clock.wall(self.prefer_s):
                return sys_s
        fill = {k: getattr(sys_s, k) for k in ("remaining_pct", "voltage_v", "current_a")
                if getattr(bat, k) is None and getattr(sys_s, k) is not None}
        return replace(bat, **fill, source="+".join(s for s in (bat.source, sys_s.source)
                                                     if s)) if fill else bat

    def _on_message(self, msg: Any) -> None:
        if msg.get_srcComponent() != self.link.cfg.target_component:
            return
        t = self.link.clock.now()
        if msg.get_type() == "SYS_STATUS":
            mv, ca, pct = int(msg.voltage_battery), int(msg.current_battery), \
                int(msg.battery_remaining)
            st = self._checked(BatteryState(
                remaining_pct=None if pct < 0 else float(pct),
                voltage_v=None if mv in (UINT16_MAX, 0) else mv / 1000.0,
                current_a=None if ca == -1 else ca / 100.0, source="SYS_STATUS", t=t))
            if st is not None:
                with self._lock:
                    self._sys = st
            return
        if int(msg.id) != self.battery_id:
            return
        mv_pack = _pack_voltage_mv([int(c) for c in msg.voltages],
                                   [int(c) for c in getattr(msg, "voltages_ext", [])])
        ca, mah, pct = int(msg.current_battery), int(msg.current_consumed), \
            int(msg.battery_remaining)
        left, cs = int(msg.time_remaining), int(msg.charge_state)
        st = self._checked(BatteryState(
            remaining_pct=None if pct < 0 else float(pct),
            voltage_v=None if mv_pack is None else mv_pack / 1000.0,
            current_a=None if ca == -1 else ca / 100.0,
            consumed_mah=None if mah < 0 else float(mah),
            time_remaining_s=float(left) if left > 0 else None,
            charge_state=cs or None, source="BATTERY_STATUS", t=t))
        if st is not None:
            with self._lock:
                self._bat, self._bat_wall = st, time.monotonic()

    def _checked(self, st: BatteryState) -> BatteryState | None:
        """The state if every value is in range, else None (counted)."""
        ok = (st.remaining_pct is None or 0.0 <= st.remaining_pct <= 100.0) and \
            (st.voltage_v is None or 0.0 < st.voltage_v < 1000.0)
        if not ok:
            self.rejected += 1
            return None
        return st
