"""The simulated battery drains with thrust, and each autopilot warns and acts on it as its
source does (:mod:`groundstation.vehicle.battery`; ArduPilot
libraries/AP_BattMonitor/AP_BattMonitor_Params.cpp BATT_LOW_VOLT / _LOW_TIMER / _FS_LOW_ACT
(Copter: 1 Land, 2 RTL, ...), PX4 src/modules/commander/commander_params.c COM_LOW_BAT_ACT
(0 warning, 2 Land, 3 Return at critical and Land at emergency) and BAT_*_THR)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from agent.wire.mavlink import ARDUPILOT_MODES as APM
from agent.wire.mavlink import px4_custom_mode
from groundstation.vehicle.dynamics import (
    BATTERY_R_OHM,
    IDLE_CURRENT_A,
    THRUST_CURRENT_A,
    battery_current,
    cell_ocv,
    initial_state,
)
from groundstation.vehicle.params import VehicleParams
from tests.sim_vehicle_helpers import M, airborne, conf, hello
from tests.vehicle_harness import Harness

P_LOITER, P_RTL, P_LAND = px4_custom_mode(4, 3), px4_custom_mode(4, 5), px4_custom_mode(4, 6)


def test_model_voltage_curve_and_current() -> None:
    """OCV: 3.27 V empty … 4.20 V full, monotonic; current = idle + k·thrust^1.5 when armed."""
    soc = np.linspace(0.0, 1.0, 101)
    v = cell_ocv(soc)
    assert v[0] == pytest.approx(3.27) and v[-1] == pytest.approx(4.20)
    assert np.all(np.diff(v) > 0)
    assert float(cell_ocv(2.0)) == pytest.approx(4.20)  # clipped
    st = initial_state(np.zeros((3, 3)))
    st.thrust = np.array([0.0, 0.5, 1.0])
    st.armed = np.array([True, True, False])
    amps = battery_current(st)
    assert amps[0] == pytest.approx(IDLE_CURRENT_A)
    assert amps[1] == pytest.approx(IDLE_CURRENT_A + THRUST_CURRENT_A * 0.5**1.5)
    assert amps[2] == pytest.approx(IDLE_CURRENT_A)  # disarmed: electronics only


def _status(h: Harness) -> Any:
    h.of("BATTERY_STATUS")
    m = h.wait_for("BATTERY_STATUS", sim_s=1.5)
    assert m is not None
    return m


def test_ardupilot_low_voltage_rtl_then_critical_capacity_land() -> None:
    params = conf(BATT_LOW_VOLT=14.8, BATT_LOW_TIMER=1, BATT_FS_LOW_ACT=2, BATT_CRT_MAH=500,
                  BATT_FS_CRT_ACT=1)
    with hello(Harness(VehicleParams(indoor=True, params=params))) as h:
        airborne(h, 3.0)
        full = _status(h)
        assert full.charge_state == M.MAV_BATTERY_CHARGE_STATE_OK
        h.fleet.state.consumed[0] = 0.85 * 5000.0  # soc 15 %: about 3.71 V a cell, sagging
        h.run(0.5)
        assert h.quad.mode == APM["GUIDED"]  # BATT_LOW_TIMER: not yet
        h.run(1.0)
        assert h.quad.mode == APM["RTL"]
        texts = [m.text for m in h.of("STATUSTEXT")]
        assert any(t.startswith("Battery 1 is low") for t in texts)
        low = _status(h)
        assert low.charge_state == M.MAV_BATTERY_CHARGE_STATE_LOW
        assert low.battery_remaining == 15  # coulomb counting on BATT_CAPACITY
        assert low.voltages[0] / 1000 < 14.8
        h.of("SYS_STATUS")
        sys = h.wait_for("SYS_STATUS", sim_s=1.5)
        assert sys.battery_remaining == 15 and abs(sys.voltage_battery - low.voltages[0]) < 100
        h.fleet.state.consumed[0] = 4600.0  # 400 mAh left < BATT_CRT_MAH
        h.run(0.3)
        assert h.quad.mode == APM["LAND"]
        assert _status(h).charge_state == M.MAV_BATTERY_CHARGE_STATE_CRITICAL
        assert h.quad.log.has("failsafe_battery_rtl") and h.quad.log.has("failsafe_battery_land")
        assert h.fleet.handler_errors == 0


def test_ardupilot_failsafe_on_the_ground_disarms_and_no_action_only_warns() -> None:
    params = conf(BATT_LOW_MAH=1000, BATT_FS_LOW_ACT=2)
    with hello(Harness(VehicleParams(indoor=True, params=params))) as h:
        h.every = h.vision
        h.run(0.3)
        assert h.set_mode(APM["LOITER"]) == M.MAV_RESULT_ACCEPTED
        assert h.arm() == M.MAV_RESULT_ACCEPTED
        h.fleet.state.consumed[0] = 4500.0
        h.run(0.3)
        assert not h.quad.armed  # landed: should_disarm_on_failsafe
    with hello(Harness(VehicleParams(indoor=True, params={"BATT_LOW_MAH": 1000}))) as h:
        airborne(h, 2.0)
        h.fleet.state.consumed[0] = 4500.0
        h.run(0.5)
        assert h.quad.mode == APM["GUIDED"]  # BATT_FS_LOW_ACT 0: warning only
        assert _status(h).charge_state == M.MAV_BATTERY_CHARGE_STATE_LOW


def test_px4_critical_returns_after_the_hold_delay_and_emergency_lands() -> None:
    params = conf(COM_LOW_BAT_ACT=3, COM_FAIL_ACT_T=1.0)
    with hello(Harness(VehicleParams(autopilot="px4", indoor=True, params=params))) as h:
        airborne(h, 3.0)
        # BAT1_CAPACITY -1: remaining from the (load-compensated) cell voltage between
        # BAT1_V_EMPTY 3.6 and BAT1_V_CHARGED 4.05 V.
        h.fleet.state.consumed[0] = 0.93 * 5000.0  # soc 7 %: 3.642 V a cell: 9.3 % → LOW
        h.run(0.3)
        st = _status(h)
        assert st.charge_state == M.MAV_BATTERY_CHARGE_STATE_LOW  # warning only
        assert st.battery_remaining == 10
        assert h.quad.mode == px4_custom_mode(6)  # still OFFBOARD
        assert any("low" in m.text for m in h.of("STATUSTEXT"))
        h.fleet.state.consumed[0] = 0.94 * 5000.0  # soc 6 %: 3.626 V: 5.8 % → CRITICAL
        h.run(0.3)
        assert _status(h).charge_state == M.MAV_BATTERY_CHARGE_STATE_CRITICAL
        assert h.quad.mode == P_LOITER  # Hold for COM_FAIL_ACT_T, then Return
        h.run(1.0)
        assert h.quad.mode == P_RTL
        h.fleet.state.consumed[0] = 0.99 * 5000.0
        h.run(0.3)
        assert _status(h).charge_state == M.MAV_BATTERY_CHARGE_STATE_EMERGENCY
        h.run(1.2)
        assert h.quad.mode == P_LAND
        assert h.fleet.handler_errors == 0


def test_battery_reports_drain_with_thrust_and_resistance_sag() -> None:
    with hello(Harness(VehicleParams(autopilot="px4", indoor=True,
                                     params={"BAT1_CAPACITY": 5000.0}))) as h:
        h.run(1.0)
        idle = _status(h)
        airborne(h, 3.0)
        flying = _status(h)
        assert flying.current_battery > 10 * idle.current_battery  # cA
        amps = flying.current_battery / 100
        soc = 1 - flying.current_consumed / 5000.0
        want = 4 * float(cell_ocv(soc)) - BATTERY_R_OHM * amps  # 4S pack
        assert flying.voltages[0] / 1000 == pytest.approx(want, abs=0.02)
        assert flying.battery_remaining == 100 - int(flying.current_consumed / 50)  # capacity
