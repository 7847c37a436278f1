"""Vehicle monitor (agent.flight.monitor): each way of losing control is detected within a
stated bound, and messages from other systems change nothing.

A simulated vehicle sends HEARTBEAT, SYS_STATUS and EXTENDED_SYS_STATE at 1 Hz each (phases
not aligned with the event); the agent calls check() at 10 Hz. Bounds on the detection
latency (event → verdict): a HEARTBEAT-borne event (mode, disarm, failsafe) ≤ 1 s + 0.1 s;
battery and landed ≤ 1 s + 0.1 s; link loss ≤ timeout (3 s) + 0.1 s after the last
HEARTBEAT, and never before the timeout.
"""

from __future__ import annotations

from dataclasses import dataclass

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mav

from agent.flight import monitor as mon
from agent.flight.monitor import MonitorConfig, VehicleMonitor, mode_name, px4_custom_mode

GUIDED_NOGPS, LAND = 20, 9
OFFBOARD = px4_custom_mode(6)
PX4_LAND = px4_custom_mode(4, 6)
CHECK_DT = 0.1
MSG_PERIOD = 1.0
BOUND_MSG = MSG_PERIOD + CHECK_DT + 1e-9


@dataclass
class _Vehicle:
    """What the vehicle would report; changed by the test at an event time."""

    mode: int = GUIDED_NOGPS
    armed: bool = True
    status: int = mav.MAV_STATE_ACTIVE
    battery: float = 80.0
    landed: int = mav.MAV_LANDED_STATE_IN_AIR
    autopilot: int = mav.MAV_AUTOPILOT_ARDUPILOTMEGA
    alive: bool = True
    last_heartbeat: float = -1.0


def _fly(m: VehicleMonitor, v: _Vehicle, event_t: float, event: dict[str, object],
         phase: float = 0.37, until: float = 30.0,
         extra: list[dict[str, int]] | None = None) -> mon.Verdict:
    """Run on a 10 ms time base from t = 0 (engaged at 0) until the verdict leaves control or
    ``until``; the event (attribute changes of ``v``) happens at ``event_t``; messages go out
    every MSG_PERIOD from ``phase``; check() runs every CHECK_DT. ``extra``: HEARTBEAT kwargs
    of other senders on the same link, sent with ours."""
    m.engage(0.0)
    next_msg, done = phase, False
    verdict = m.check(0.0)
    for tick in range(round(until * 100)):
        t = tick / 100
        if not done and t >= event_t:
            for key, value in event.items():
                setattr(v, key, value)
            done = True
        if t >= next_msg - 1e-9:
            next_msg += MSG_PERIOD
            if v.alive:
                base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (128 if v.armed else 0)
                m.on_heartbeat(t, 1, 1, base, v.mode, v.status, v.autopilot)
                v.last_heartbeat = t
                m.on_sys_status(t, v.battery, 15.8, sysid=1, compid=1)
                m.on_extended_sys_state(t, v.landed, sysid=1, compid=1)
            for hb in extra or []:
                m.on_heartbeat(t, **hb)
        if tick % round(CHECK_DT * 100) == 0:
            verdict = m.check(t)
            if not verdict.in_control:
                return verdict
    return verdict


def _ardupilot(config: MonitorConfig | None = None) -> VehicleMonitor:
    return VehicleMonitor("ardupilot", [GUIDED_NOGPS], target_system=1, own_system=1,
                          own_component=191, config=config)


def test_constants_match_pymavlink() -> None:
    for name in ("MAV_AUTOPILOT_ARDUPILOTMEGA", "MAV_AUTOPILOT_INVALID", "MAV_AUTOPILOT_PX4",
                 "MAV_MODE_FLAG_SAFETY_ARMED", "MAV_STATE_CRITICAL", "MAV_STATE_EMERGENCY",
                 "MAV_STATE_FLIGHT_TERMINATION", "MAV_LANDED_STATE_ON_GROUND",
                 "MAV_LANDED_STATE_IN_AIR", "MAV_BATTERY_CHARGE_STATE_CRITICAL",
                 "MAV_BATTERY_CHARGE_STATE_EMERGENCY", "MAV_BATTERY_CHARGE_STATE_FAILED",
                 "MAV_BATTERY_CHARGE_STATE_UNHEALTHY"):
        assert getattr(mon, name) == getattr(mav, name), name


def test_mode_tables_agree_with_pymavlink() -> None:
    """Independent copy: pymavlink's ArduCopter table and its PX4 (main, sub) map."""
    for number, name in mon.ARDUCOPTER_MODES.items():
        assert mavutil.mode_mapping_acm[number] == name
    for name, (_, main, sub) in mavutil.px4_map.items():
        if name in ("RTGS", "FOLLOWME"):  # RTGS removed from PX4; FOLLOWME named differently
            continue
        assert mode_name("px4", px4_custom_mode(main, sub)).split(".")[-1] == name
    assert mode_name("px4", OFFBOARD) == "OFFBOARD" and mode_name("px4", PX4_LAND) == "AUTO.LAND"
    assert mode_name("ardupilot", 99) == "MODE_99"


def test_in_control_while_nothing_happens() -> None:
    m = _ardupilot()
    assert m.check(0.0).code == "idle" and not m.check(0.0).in_control
    verdict = _fly(m, _Vehicle(), event_t=1e9, event={}, until=20.0)
    assert verdict.in_control and verdict.code == ""


@pytest.mark.parametrize("event_t", [5.03, 5.52, 5.96])
def test_link_lost(event_t: float) -> None:
    v = _Vehicle()
    verdict = _fly(_ardupilot(), v, event_t, {"alive": False})
    assert verdict.code == "link_lost"
    since_hb = verdict.t - v.last_heartbeat
    assert 3.0 < since_hb <= 3.0 + CHECK_DT + 1e-9
    assert verdict.t - event_t <= 3.0 + CHECK_DT + 1e-9


@pytest.mark.parametrize(("event", "code", "words"), [
    ({"mode": 5}, "mode_changed", "LOITER (5)"),  # the pilot flips the mode switch
    ({"mode": LAND}, "mode_changed", "LAND (9)"),  # failsafe LAND
    ({"armed": False}, "disarmed", "disarmed"),
    ({"status": mav.MAV_STATE_CRITICAL}, "autopilot_failsafe", "failsafe"),
    ({"status": mav.MAV_STATE_EMERGENCY}, "autopilot_failsafe", "failsafe"),
    ({"battery": 12.0}, "battery_critical", "12 %"),
    ({"landed": mav.MAV_LANDED_STATE_ON_GROUND}, "landed", "landed"),
])
@pytest.mark.parametrize("event_t", [4.05, 4.6])
def test_each_cause_is_detected_within_the_bound(event: dict[str, object], code: str,
                                                 words: str, event_t: float) -> None:
    verdict = _fly(_ardupilot(), _Vehicle(), event_t, event)
    assert not verdict.in_control and verdict.code == code
    assert words in verdict.reason and "\n" not in verdict.reason
    assert 0.0 <= verdict.t - event_t <= BOUND_MSG


def test_failsafe_land_is_latched_as_its_first_cause() -> None:
    """ArduCopter's failsafe: CRITICAL and LAND in the same HEARTBEAT, then disarm on touchdown:
    the verdict keeps the first cause."""
    m, v = _ardupilot(), _Vehicle()
    verdict = _fly(m, v, 2.5, {"mode": LAND, "status": mav.MAV_STATE_CRITICAL})
    assert verdict.code == "autopilot_failsafe" and "LAND" in verdict.reason
    m.on_heartbeat(verdict.t + 5, 1, 1, 0, LAND, mav.MAV_STATE_STANDBY, 3)
    assert m.check(verdict.t + 5).code == "autopilot_failsafe"
    m.engage(100.0)
    assert m.check(100.0).in_control  # re-engaged after a new handshake


def test_battery_status_charge_state_and_voltage() -> None:
    m = _ardupilot(config=MonitorConfig(battery_critical_pct=10.0, battery_critical_v=13.2))
    m.engage(0.0)
    m.on_heartbeat(0.0, 1, 1, 128, GUIDED_NOGPS, 4, 3)
    m.on_battery_status(0.5, -1.0, charge_state=mav.MAV_BATTERY_CHARGE_STATE_OK)
    assert m.check(0.5).in_control  # unknown remaining, charge OK
    m.on_sys_status(0.6, -1.0, 13.1)
    assert m.check(0.6).code == "battery_critical" and "13.10 V" in m.check(0.6).reason
    m2 = _ardupilot()
    m2.engage(0.0)
    m2.on_battery_status(0.5, 40.0, charge_state=mav.MAV_BATTERY_CHARGE_STATE_CRITICAL)
    assert m2.check(0.5).code == "battery_critical"


def test_other_systems_change_nothing() -> None:
    """A GCS (255), a camera on our system (component 100) and another drone (system 2) in
    LAND, disarmed and CRITICAL: ignored. When our vehicle falls silent, the others' HEARTBEATs
    do not keep the link alive."""
    others = [
        {"sysid": 255, "compid": 190, "base_mode": 0, "custom_mode": 0,
         "system_status": 4, "autopilot": mav.MAV_AUTOPILOT_INVALID},
        {"sysid": 1, "compid": 100, "base_mode": 0, "custom_mode": 0,
         "system_status": 4, "autopilot": mav.MAV_AUTOPILOT_INVALID},
        {"sysid": 2, "compid": 1, "base_mode": 0, "custom_mode": LAND,
         "system_status": mav.MAV_STATE_CRITICAL, "autopilot": 3},
    ]
    m, v = _ardupilot(), _Vehicle()
    assert _fly(m, v, 1e9, {}, until=15.0, extra=others).in_control
    m.on_sys_status(15.0, 5.0, 10.0, sysid=2, compid=1)  # the other drone's empty battery
    m.on_extended_sys_state(15.0, mav.MAV_LANDED_STATE_ON_GROUND, sysid=2, compid=1)
    assert m.check(15.0).in_control
    verdict = _fly(_ardupilot(), _Vehicle(), 5.0, {"alive": False}, extra=others)
    assert verdict.code == "link_lost" and verdict.t <= 5.0 + 3.0 + CHECK_DT + 1e-9


def test_command_acks_addressed_to_us() -> None:
    m = _ardupilot()
    arm = mav.MAV_CMD_COMPONENT_ARM_DISARM
    assert m.ack_matches(arm, 1, 191, expected_command=arm)
    assert m.ack_matches(arm, 0, 0)  # MAVLink 1 ACK: no target fields
    assert not m.ack_matches(arm, 2, 191)  # to another system (a second companion)
    assert not m.ack_matches(arm, 1, 190)  # to the GCS on our system id
    assert not m.ack_matches(mav.MAV_CMD_DO_SET_MODE, 1, 191, expected_command=arm)
    assert not m.on_command_ack(1.0, arm, 4, 2, 191, sysid=1, compid=1)
    assert m.last_ack(arm) is None  # the other system's FAILED is not ours
    assert not m.on_command_ack(1.1, arm, 0, 1, 191, sysid=2, compid=1)  # from another drone
    assert m.on_command_ack(1.2, arm, mav.MAV_RESULT_ACCEPTED, 1, 191, sysid=1, compid=1)
    assert m.last_ack(arm) == mav.MAV_RESULT_ACCEPTED
    assert m.last_ack(arm, since=2.0) is None


def test_px4_offboard_and_its_failsafe_land() -> None:
    m = VehicleMonitor("px4", [OFFBOARD], target_system=1)
    v = _Vehicle(mode=OFFBOARD, autopilot=mav.MAV_AUTOPILOT_PX4)
    verdict = _fly(m, v, 6.2, {"mode": PX4_LAND})  # COM_OF_LOSS_T expired → AUTO.LAND
    assert verdict.code == "mode_changed" and "AUTO.LAND" in verdict.reason
    assert verdict.t - 6.2 <= BOUND_MSG


def test_rejects_bad_configuration() -> None:
    with pytest.raises(ValueError):
        VehicleMonitor("inav", [0], target_system=1)
    with pytest.raises(ValueError):
        VehicleMonitor("ardupilot", [], target_system=1)
    with pytest.raises(ValueError):
        VehicleMonitor("ardupilot", [20], target_system=0)
    with pytest.raises(ValueError):
        MonitorConfig(heartbeat_timeout_s=0.0)
