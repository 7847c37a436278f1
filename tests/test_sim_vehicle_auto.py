"""The simulated vehicles fly a stored mission in AUTO as ArduCopter and PX4 do
(:mod:`groundstation.vehicle.mission_exec`; sources: ArduCopter/mode_auto.cpp,
libraries/AP_Mission, GCS_Common.cpp; PX4 src/modules/navigator mission_base.cpp,
mission_block.cpp, Commander.cpp): item by item, MISSION_ITEM_REACHED in order (which items
each reports), the camera and gimbal items, DO_CHANGE_SPEED, the end of the mission, what each
refuses, MISSION_SET_CURRENT and the RTL item. Raw pymavlink on the manual clock; the vehicles
fly on forwarded mocap (the EKF's estimate is the true pose: the camera's logged positions are
exact)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray

from agent.flight.frames import euler_from_quat
from agent.wire.mavlink import px4_custom_mode
from groundstation.vehicle.conventions import geodetic
from groundstation.vehicle.params import VehicleParams
from tests.sim_vehicle_helpers import (
    NAN,
    Flown,
    M,
    MissionItem,
    command,
    fly,
    hello,
    ned,
    upload_mission,
)
from tests.vehicle_harness import Harness

Array = NDArray[np.float64]
AP_AUTO, AP_GUIDED = 3, 4
P_MISSION, P_LOITER, P_RTL = px4_custom_mode(4, 4), px4_custom_mode(4, 3), px4_custom_mode(4, 5)
P_POSCTL = px4_custom_mode(3)
REL = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
LOCK = (M.GIMBAL_MANAGER_FLAGS_ROLL_LOCK | M.GIMBAL_MANAGER_FLAGS_PITCH_LOCK
        | M.GIMBAL_MANAGER_FLAGS_YAW_LOCK)


def _vehicle(autopilot: str, **params: float) -> Harness:
    """Camera and gimbal fitted, external navigation from the forwarded mocap."""
    h = hello(Harness(VehicleParams(autopilot=autopilot, payload=True, indoor=True,
                                    params=dict(params))))
    h.every = h.vision
    return h


def at(h: Harness, cmd: int, north: float, east: float, alt: float,
       p: tuple[float, float, float, float] = (0.0, 0.0, 0.0, NAN)) -> MissionItem:
    """A NAV item at (north, east) [m from the EKF origin], ``alt`` [m above home]."""
    lat, lon, _ = geodetic(h.quad.origin, np.array([north, east, 0.0]))
    return MissionItem(REL, cmd, p, lat, lon, alt)


def do(cmd: int, p: tuple[float, float, float, float], x: int = 0, y: int = 0,
       z: float = 0.0) -> MissionItem:
    """A DO item (MAV_FRAME_MISSION)."""
    return MissionItem(M.MAV_FRAME_MISSION, cmd, p, x, y, z)


def home(h: Harness) -> MissionItem:
    """ArduPilot's item 0 (home; overwritten by the vehicle's own home)."""
    lat, lon, alt = geodetic(h.quad.origin, np.zeros(3))
    return MissionItem(M.MAV_FRAME_GLOBAL_INT, M.MAV_CMD_NAV_WAYPOINT, (0, 0, 0, 0), lat, lon,
                       alt / 1000.0)


TAKEOFF, WP, LAND, RTL = (M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_LAND,
                          M.MAV_CMD_NAV_RETURN_TO_LAUNCH)
GIMBAL = M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW


def gimbal(pitch: float, yaw: float) -> MissionItem:
    """The exported plans' gimbal item: angles [deg], earth-frame yaw (LOCK flags in x)."""
    return do(GIMBAL, (pitch, yaw, NAN, NAN), LOCK)


SHOT = do(M.MAV_CMD_IMAGE_START_CAPTURE, (0.0, 0.0, 1.0, 0.0))
TAKE_CONTROL = do(M.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, (-2.0, -2.0, -1.0, -1.0))
DELAY = MissionItem(M.MAV_FRAME_MISSION, M.MAV_CMD_NAV_DELAY, (1.0, -1.0, -1.0, -1.0))


def start_ardupilot(h: Harness) -> None:
    """What MAVProxy / a GCS does without RC: GUIDED, arm, MAV_CMD_MISSION_START."""
    assert h.set_mode(AP_GUIDED) == M.MAV_RESULT_ACCEPTED
    assert h.arm() == M.MAV_RESULT_ACCEPTED
    assert command(h, M.MAV_CMD_MISSION_START, 0, 0).result == M.MAV_RESULT_ACCEPTED


def start_px4(h: Harness) -> None:
    """What MAVSDK does: arm, then the mode AUTO.MISSION (``mission.start_mission``)."""
    assert h.arm() == M.MAV_RESULT_ACCEPTED
    assert h.set_mode(4, 4) == M.MAV_RESULT_ACCEPTED


def _speeds(run: Flown, t0: float, t1: float) -> float:
    """Largest horizontal speed [m/s] between t0 and t1 [s sim]."""
    return max(float(np.hypot(v[0], v[1])) for t, _, v in run.path if t0 <= t <= t1)


def test_ardupilot_flies_its_mission_item_by_item() -> None:
    """ArduCopter AUTO: NAV items and the copter's own DO items reported (not AP_Mission's
    camera and gimbal items), each waypoint reached at its position (the target arrives and
    the hold passes there), one CAMERA_FEEDBACK per camera item with the gimbal at the
    commanded pitch, DO_CHANGE_SPEED caps the next leg, the LAND item disarms on touchdown
    and is never reported, and the disarm resets the mission to its first item."""
    with _vehicle("ardupilot") as h:
        items = [home(h), at(h, TAKEOFF, 0, 0, 3.0), gimbal(-40.0, 90.0),
                 at(h, WP, 4, 0, 3.0, (1.0, 0.5, 0.0, NAN)), SHOT, DELAY,
                 do(M.MAV_CMD_DO_CHANGE_SPEED, (1.0, 1.5, -1.0, 0.0)), gimbal(-10.0, 0.0),
                 at(h, WP, 4, 4, 4.0, (1.0, 0.5, 0.0, NAN)),
                 do(M.MAV_CMD_DO_DIGICAM_CONTROL, (0.0, 0.0, 0.0, 0.0), 1),
                 at(h, LAND, 0, 0, 0.0)]
        assert upload_mission(h, items) == M.MAV_MISSION_ACCEPTED
        start_ardupilot(h)
        run = fly(h, 60.0, lambda h: not h.quad.armed)
        assert not h.quad.armed and h.quad.mode == AP_AUTO
        assert run.seqs == [1, 3, 5, 6, 8]  # LAND disarms instead (verify_land)
        wp3 = np.array([4.0, 0.0, -3.0])
        wp6 = np.array([4.0, 4.0, -4.0])
        assert np.linalg.norm(run.where(3) - wp3) < 0.1
        assert np.linalg.norm(run.where(5) - wp3) < 0.1  # NAV_DELAY: stayed there
        assert np.linalg.norm(run.where(8) - wp6) < 0.1
        assert [m.get_type() for m in run.shots] == ["CAMERA_FEEDBACK"] * 2
        assert [m.img_idx for m in run.shots] == [1, 2]
        for shot, wp in zip(run.shots, (wp3, wp6), strict=True):
            assert np.linalg.norm(ned(h, shot.lat, shot.lng, round(shot.alt_msl * 1000)) - wp) \
                < 0.1
        assert run.shot_pitch == pytest.approx([-40.0, -10.0], abs=0.5)
        t3 = next(t for t, p, _ in run.path if np.linalg.norm(p - wp3) < 0.1)
        t6 = next(t for t, p, _ in run.path if t > t3 + 1.5 and np.linalg.norm(p - wp6) < 0.1)
        assert _speeds(run, 0.0, t3) > 2.5  # a 4 m leg at WPNAV_SPEED / WPNAV_ACCEL
        assert 1.3 < _speeds(run, t3 + 1.1, t6) < 1.8  # DO_CHANGE_SPEED 1.5 m/s (tracking)
        assert np.linalg.norm(h.fleet.p[0]) < 0.1  # landed at the LAND item's location
        last = run.current[-1]
        assert (last.seq, last.total, last.mission_mode) == (1, 10, 1)  # reset by the disarm
        assert h.fleet.handler_errors == 0


def test_px4_flies_its_mission_item_by_item() -> None:
    """PX4 AUTO.MISSION: every item reported in order, the waypoint within its acceptance
    radius flying the item's yaw, the camera component's CAMERA_IMAGE_CAPTURED at each camera
    item with the gimbal's attitude in it (the autopilot took the gimbal first; NAV_DELAY holds
    the vehicle and the next gimbal item until the exposure is done), the LAND item reported
    once landed, the mission complete, COM_DISARM_LAND disarms in the mode."""
    with _vehicle("px4") as h:
        items = [at(h, TAKEOFF, 0, 0, 3.0), TAKE_CONTROL, gimbal(-40.0, 90.0),
                 at(h, WP, 4, 0, 3.0, (1.0, 0.5, 0.0, 90.0)), SHOT, DELAY,
                 do(M.MAV_CMD_DO_CHANGE_SPEED, (1.0, 1.5, -1.0, 0.0)), gimbal(-10.0, 0.0),
                 at(h, WP, 4, 4, 4.0, (1.0, 0.5, 0.0, NAN)), SHOT, at(h, LAND, 4, 4, 0.0)]
        assert upload_mission(h, items) == M.MAV_MISSION_ACCEPTED
        start_px4(h)
        run = fly(h, 60.0, lambda h: not h.quad.armed)
        assert not h.quad.armed and h.quad.mode == P_MISSION
        assert run.seqs == list(range(len(items)))
        wp3, wp8 = np.array([4.0, 0.0, -3.0]), np.array([4.0, 4.0, -4.0])
        for seq, wp in ((3, wp3), (8, wp8)):  # reached + 1 s hold: well inside 0.5 m
            assert np.linalg.norm(run.where(seq) - wp) < 0.1
        assert [m.get_type() for m in run.shots] == ["CAMERA_IMAGE_CAPTURED"] * 2
        assert [m.image_index for m in run.shots] == [0, 1]
        assert all(m.get_srcComponent() == M.MAV_COMP_ID_CAMERA for m in run.shots)
        for shot, wp, want in zip(run.shots, (wp3, wp8), ((-40.0, 90.0), (-10.0, 0.0)),
                                  strict=True):
            assert np.linalg.norm(ned(h, shot.lat, shot.lon, shot.alt) - wp) < 0.1
            _roll, pitch, yaw = euler_from_quat(np.array(shot.q, dtype=np.float64))
            assert math.degrees(pitch) == pytest.approx(want[0], abs=0.5)
            assert math.degrees(yaw) == pytest.approx(want[1], abs=1.0)  # earth-frame yaw lock
        t3 = next(t for t, p, _ in run.path if np.linalg.norm(p - wp3) < 0.1)
        assert _speeds(run, 0.0, t3) > 2.5
        assert "Mission finished, landed" in run.texts
        assert run.current[-1].mission_state == M.MISSION_STATE_COMPLETE
        assert h.fleet.handler_errors == 0


def test_px4_mission_gimbal_items_need_the_autopilot_in_control() -> None:
    """Without the configure item PX4's gimbal refuses the mission's own PITCHYAW (it comes
    from the autopilot, not the primary control): the picture is taken level."""
    with _vehicle("px4") as h:
        items = [at(h, TAKEOFF, 0, 0, 2.0), gimbal(-40.0, 0.0),
                 at(h, WP, 1, 0, 2.0, (1.0, 0.5, 0.0, NAN)), SHOT, at(h, LAND, 1, 0, 0.0)]
        assert upload_mission(h, items) == M.MAV_MISSION_ACCEPTED
        start_px4(h)
        run = fly(h, 40.0, lambda h: not h.quad.armed)
        assert run.seqs == list(range(len(items)))  # reported all the same
        (shot,) = run.shots
        assert math.degrees(euler_from_quat(np.array(shot.q, dtype=np.float64))[1]) == \
            pytest.approx(0.0, abs=0.5)
        assert h.quad.log.has("mission_gimbal_refused")


def test_px4_exposes_after_the_mission_moved_on_without_a_delay() -> None:
    """PX4 goes on with the next items as soon as its camera item is out, and the camera
    component exposes after its latency: with the next gimbal item right after the camera
    item, the gimbal has begun turning by the exposure (why exported plans wait with
    NAV_DELAY after each image)."""
    with _vehicle("px4") as h:
        items = [at(h, TAKEOFF, 0, 0, 2.0), TAKE_CONTROL, gimbal(-40.0, 0.0),
                 at(h, WP, 1, 0, 2.0, (1.0, 0.5, 0.0, NAN)), SHOT, gimbal(0.0, 0.0),
                 at(h, WP, 2, 0, 2.0, (1.0, 0.5, 0.0, NAN)), at(h, LAND, 2, 0, 0.0)]
        assert upload_mission(h, items) == M.MAV_MISSION_ACCEPTED
        start_px4(h)
        run = fly(h, 40.0, lambda h: not h.quad.armed)
        (shot,) = run.shots
        pitch = math.degrees(euler_from_quat(np.array(shot.q, dtype=np.float64))[1])
        assert -40.0 + 1.0 < pitch < -40.0 + 10.0  # turning at 60 °/s for the latency


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_end_of_mission(autopilot: str) -> None:
    """A mission ending in the air: ArduCopter stays in AUTO loitering there, PX4 says
    "Mission finished, loitering" and switches to AUTO.LOITER over the last waypoint; both
    report the mission complete."""
    px4 = autopilot == "px4"
    with _vehicle(autopilot) as h:
        items = [at(h, TAKEOFF, 0, 0, 2.0), at(h, WP, 3, 0, 2.5, (0.0, 0.5, 0.0, NAN))]
        assert upload_mission(h, items if px4 else [home(h), *items]) == M.MAV_MISSION_ACCEPTED
        start_px4(h) if px4 else start_ardupilot(h)
        last = len(items) - (1 if px4 else 0)
        fly(h, 30.0, lambda h: h.quad.mission.state == "complete")
        run = fly(h, 3.0, lambda h: False)
        assert h.quad.armed and h.quad.mode == (P_LOITER if px4 else AP_AUTO)
        wp = np.array([3.0, 0.0, -2.5])
        dist = [float(np.linalg.norm(p - wp)) for _, p, _ in run.path]
        assert max(dist) < 0.6 and dist[-1] < 0.1  # loiters there
        assert run.current[-1].mission_state == M.MISSION_STATE_COMPLETE
        assert run.current[-1].seq == last
        assert run.current[-1].mission_mode == (0 if px4 else 1)


def test_ardupilot_refusals() -> None:
    """ArduCopter: AUTO armed without a mission FAILED; armed on the ground with a mission whose
    first NAV item is no takeoff FAILED ("Auto: Missing Takeoff Cmd"); while disarmed any mode
    is taken but arming in AUTO is FAILED unless AUTO_OPTIONS bit 0; in AUTO on the ground the
    takeoff waits for the throttle (no RC here) until MAV_CMD_MISSION_START; MISSION_START
    disarmed FAILED."""
    with _vehicle("ardupilot") as h:
        assert command(h, M.MAV_CMD_MISSION_START, 0, 0).result == M.MAV_RESULT_FAILED
        assert h.set_mode(AP_GUIDED) == M.MAV_RESULT_ACCEPTED
        assert h.arm() == M.MAV_RESULT_ACCEPTED
        assert h.set_mode(AP_AUTO) == M.MAV_RESULT_FAILED  # no mission
        assert upload_mission(h, [home(h), at(h, WP, 2, 0, 2.0)]) == M.MAV_MISSION_ACCEPTED
        assert h.set_mode(AP_AUTO) == M.MAV_RESULT_FAILED
        assert "Auto: Missing Takeoff Cmd" in [m.text for m in h.of("STATUSTEXT")]
        assert h.arm(False) == M.MAV_RESULT_ACCEPTED
        items = [home(h), at(h, TAKEOFF, 0, 0, 2.0), at(h, WP, 2, 0, 2.0)]
        assert upload_mission(h, items) == M.MAV_MISSION_ACCEPTED
        assert h.set_mode(AP_AUTO) == M.MAV_RESULT_ACCEPTED  # disarmed: no checks
        assert h.arm() == M.MAV_RESULT_FAILED  # AUTO_OPTIONS 0: no arming in AUTO
        h.client.mav.param_set_send(1, 1, b"AUTO_OPTIONS", 1.0, M.MAV_PARAM_TYPE_INT32)
        assert h.wait_for("PARAM_VALUE") is not None
        assert h.arm() == M.MAV_RESULT_ACCEPTED
        h.run(2.0)
        assert h.altitude() < 0.01  # the takeoff waits for the pilot's throttle
        assert command(h, M.MAV_CMD_MISSION_START, 0, 0).result == M.MAV_RESULT_ACCEPTED
        h.run(2.0)
        assert h.altitude() > 1.0


def test_px4_refusals() -> None:
    """PX4: AUTO.MISSION armed without a mission TEMPORARILY_REJECTED; taken while disarmed,
    but arming in it needs a mission; MAV_CMD_MISSION_START is the mode change (param1 the
    first item)."""
    with _vehicle("px4") as h:
        assert h.set_mode(P_POSCTL) == M.MAV_RESULT_ACCEPTED
        assert h.arm() == M.MAV_RESULT_ACCEPTED
        assert h.set_mode(4, 4) == M.MAV_RESULT_TEMPORARILY_REJECTED
        assert h.arm(False) == M.MAV_RESULT_ACCEPTED
        assert h.set_mode(4, 4) == M.MAV_RESULT_ACCEPTED
        assert h.arm() == M.MAV_RESULT_TEMPORARILY_REJECTED
        assert h.set_mode(P_POSCTL) == M.MAV_RESULT_ACCEPTED
        items = [at(h, TAKEOFF, 0, 0, 2.0), at(h, WP, 2, 0, 2.0), at(h, WP, 0, 2, 2.0)]
        assert upload_mission(h, items) == M.MAV_MISSION_ACCEPTED
        assert h.arm() == M.MAV_RESULT_ACCEPTED
        ack = command(h, M.MAV_CMD_MISSION_START, 0, 0)
        assert ack.result == M.MAV_RESULT_ACCEPTED and h.quad.mode == P_MISSION
        run = fly(h, 20.0, lambda h: h.quad.mode != P_MISSION)
        assert run.seqs == [0, 1, 2] and h.quad.mode == P_LOITER


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_mission_set_current(autopilot: str) -> None:
    """MISSION_SET_CURRENT in flight jumps to that item (the skipped waypoint is never
    reported), answered by MISSION_CURRENT; out of range: ArduCopter ignores it, PX4 says
    "WPM: WP CURR CMD: Not in list"."""
    px4 = autopilot == "px4"
    with _vehicle(autopilot) as h:
        items = [at(h, TAKEOFF, 0, 0, 2.0), at(h, WP, 3, 0, 2.0), at(h, WP, 6, 0, 2.0),
                 at(h, WP, 6, 3, 2.0)]
        if not px4:
            items = [home(h), *items]
        skip, jump = len(items) - 3, len(items) - 1
        assert upload_mission(h, items) == M.MAV_MISSION_ACCEPTED
        start_px4(h) if px4 else start_ardupilot(h)
        fly(h, 20.0, lambda h: h.quad.mission.cur == skip)
        h.client.mav.mission_set_current_send(1, 1, jump)
        current = h.wait_for("MISSION_CURRENT", lambda m: m.seq == jump)
        assert current is not None
        h.client.mav.mission_set_current_send(1, 1, 99)
        run = fly(h, 20.0, lambda h: h.quad.mission.state == "complete")
        assert skip not in run.seqs and run.seqs[-1] == jump
        assert ("WPM: WP CURR CMD: Not in list" in run.texts) == px4
        fly(h, 4.0, lambda h: False)  # PX4 completes within NAV_ACC_RAD, then loiters there
        assert np.linalg.norm(h.fleet.p[0] - np.array([6.0, 3.0, -2.0])) < 0.3


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_return_to_launch_item(autopilot: str) -> None:
    """NAV_RETURN_TO_LAUNCH: ArduCopter flies RTL inside AUTO (climb to RTL_ALT, home, land),
    reports the item once landed, and exit_mission disarms; PX4 reports it at once and
    switches to AUTO.RTL."""
    px4 = autopilot == "px4"
    with _vehicle(autopilot, **({"RTL_RETURN_ALT": 3.0} if px4 else {"RTL_ALT": 300})) as h:
        items = [at(h, TAKEOFF, 0, 0, 2.0), at(h, WP, 3, 0, 2.0, (0.0, 0.5, 0.0, NAN)),
                 MissionItem(M.MAV_FRAME_MISSION, RTL, (0, 0, 0, 0))]
        if not px4:
            items = [home(h), *items]
        assert upload_mission(h, items) == M.MAV_MISSION_ACCEPTED
        start_px4(h) if px4 else start_ardupilot(h)
        run = fly(h, 40.0, lambda h: not h.quad.armed or h.quad.mode == P_RTL)
        assert run.seqs[-1] == len(items) - 1
        if px4:
            assert h.quad.mode == P_RTL and h.quad.armed
        else:
            assert not h.quad.armed and h.quad.mode == AP_AUTO
            assert np.linalg.norm(h.fleet.p[0]) < 0.2  # landed at home
            assert min(float(p[2]) for _, p, _ in run.path) < -2.9  # climbed to RTL_ALT
