"""Flying real autopilots, checked against the simulated vehicle through the real driver:
the hover thrust seeded from the autopilot and re-estimated in flight, the vehicle monitor
for the whole flight (each way of losing the vehicle, detection bound, nothing commanded
afterwards), COMMAND_ACK matching, a failed handshake, the pre-flight check per flavour (and
``viscover preflight``), and a serial connection over a pseudo-terminal pair.

Detection bounds (simulation seconds, from the event): a HEARTBEAT-borne event (mode change,
disarm, the autopilot's failsafe) ≤ 1 s (HEARTBEAT period) + 0.3 s (check period and
scheduling at 3× real time); battery ≤ 1 s (SYS_STATUS / BATTERY_STATUS period) + 0.3 s;
link loss ≥ 3 s and ≤ 3 s + 0.3 s after the last HEARTBEAT (so ≤ 3 + 1 + 0.3 s after the
link went silent).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agent.cli import main
from agent.flight.autopilot_check import check_autopilot
from agent.flight.driver_types import DriverConfig, FlightError, decode_param_value
from agent.wire.mavlink import ARDUPILOT_MODES, mavlink, mavutil, px4_custom_mode
from bench.bench_flight import FlightRig, altitude_errors
from groundstation.vehicle.params import VehicleParams
from tests.conftest import stop_process, wait_until

HB_BOUND = 1.0 + 0.3
LINK_BOUND = 3.0 + 1.0 + 0.3


# -- hover thrust -------------------------------------------------------------------------

@pytest.mark.parametrize("hover_true", [
    0.2, pytest.param(0.35, marks=pytest.mark.long), pytest.param(0.5, marks=pytest.mark.long),
    0.7])  # the two ends in make test, all four in make test-long (make test's time budget)
def test_altitude_held_for_any_hover_thrust_and_after_a_mass_step(hover_true: float) -> None:
    """True hover thrust 0.2..0.7 (the autopilot's MOT_THST_HOVER seeds the estimate): within
    0.1 m of 1 m after settling; +30 % mass (0.7 → 0.91 is beyond the 0.9 thrust limit, so not
    there): within 0.1 m again and the estimate follows the new hover thrust."""
    r = altitude_errors(hover_true, mass_step=hover_true < 0.6)
    assert r["err_m"] < 0.1, r
    assert r["estimate"] == pytest.approx(hover_true, abs=0.03)
    if hover_true < 0.6:
        assert r["err_after_step_m"] < 0.1, r
        assert r["estimate_after_step"] == pytest.approx(1.3 * hover_true, abs=0.03)
    assert r["setpoints_blocked"] == 0


@pytest.mark.parametrize("hover_true", [0.2])
def test_a_hover_thrust_the_autopilot_never_learnt_is_estimated(hover_true: float) -> None:
    """MOT_THST_HOVER left at its default 0.35 on a 0.2 airframe (heavier: the next test)."""
    r = altitude_errors(hover_true, seed=0.35, mass_step=False)
    assert r["err_m"] < 0.1, r
    assert r["estimate"] == pytest.approx(hover_true, abs=0.03)


def test_an_airframe_heavier_than_its_seed_still_lifts_off() -> None:
    """True hover thrust 0.75, MOT_THST_HOVER 0.35: the largest acceleration the controller
    commands on the seed (4 m/s², thrust 0.49) never lifts it, so after 1 s on the ground
    the hover thrust is raised at 0.15/s until it leaves the ground; then the estimate
    converges and the altitude holds."""
    r = altitude_errors(0.75, seed=0.35, mass_step=False, settle_s=12.0)
    assert r["err_m"] < 0.1, r
    assert r["estimate"] == pytest.approx(0.75, abs=0.03)


def test_failsafe_levels_at_the_current_hover_estimate() -> None:
    """The stale-mocap failsafe sends the hover thrust the controller uses now (0.25 here),
    not the configured model's 0.5."""
    with FlightRig(VehicleParams(hover_thrust=0.25)) as rig:
        rig.take_off(0.8)
        rig.run_for(3.0)
        assert rig.controller.cfg.model.hover_thrust == 0.5
        rig.feeding = False
        rig.run_for(0.8)
        assert rig.driver.phase == "failsafe_hold"
        assert rig.quad.log.last_thrust == pytest.approx(rig.controller.model.hover_thrust)
        assert rig.quad.log.last_thrust == pytest.approx(0.25, abs=0.02)


# -- monitoring -----------------------------------------------------------------------------

def _hovering(rig: FlightRig) -> None:
    rig.take_off(0.8)
    rig.run_for(2.5)
    assert rig.driver.phase == "flying" and rig.driver.released is None


def _wait_release(rig: FlightRig, limit_s: float = 8.0) -> Any:
    end = rig.clock.now() + limit_s
    while rig.driver.released is None and rig.clock.now() < end:
        time.sleep(rig.clock.wall(0.01))
    return rig.driver.released


def _nothing_commanded_after(rig: FlightRig, mode: int, seconds: float = 1.5) -> None:
    """No set-point reaches the vehicle any more and its mode stays what the pilot or the
    autopilot chose."""
    time.sleep(0.2)
    before = rig.quad.log.setpoints
    rig.run_for(seconds)
    assert rig.quad.log.setpoints == before
    assert not rig.driver.streaming and rig.driver.phase == "released"
    assert rig.quad.mode == mode


def _pilot(rig: FlightRig) -> Any:
    """A ground station (system 255) on the vehicle's link."""
    return mavutil.mavlink_connection(f"udpout:127.0.0.1:{rig.quad.port}", source_system=255,
                                      source_component=190)


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_pilot_mode_change_is_never_fought(autopilot: str) -> None:
    params = VehicleParams(autopilot=autopilot, indoor=True)
    with FlightRig(params) as rig:
        _hovering(rig)
        gcs = _pilot(rig)
        try:
            target = ARDUPILOT_MODES["LOITER"] if autopilot == "ardupilot" else 3  # POSCTL
            t0 = rig.clock.now()
            gcs.mav.command_long_send(1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0,
                                      mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, target,
                                      0, 0, 0, 0, 0)
            r = _wait_release(rig)
            assert r is not None and r.code == "mode_changed", r
            assert r.t - t0 <= HB_BOUND
            mode = target if autopilot == "ardupilot" else px4_custom_mode(target)
            _nothing_commanded_after(rig, mode)
            assert not rig.driver.land(wait=False)  # we never command LAND over the pilot
            assert rig.quad.mode == mode and rig.quad.armed
        finally:
            gcs.close()


def test_autopilot_failsafe_land_is_detected() -> None:
    """The autopilot switches to LAND itself (a failsafe): detected, not fought, it lands."""
    with FlightRig(VehicleParams(indoor=True)) as rig:
        _hovering(rig)
        t0 = rig.clock.now()
        rig.quad.enter_mode(ARDUPILOT_MODES["LAND"], rig.fleet.t)
        r = _wait_release(rig)
        assert r is not None and r.code == "mode_changed" and "LAND" in r.reason
        assert r.t - t0 <= HB_BOUND
        _nothing_commanded_after(rig, ARDUPILOT_MODES["LAND"])
        assert wait_until(lambda: not rig.quad.armed, 10.0)  # the autopilot landed it


def test_disarm_is_detected() -> None:
    with FlightRig(VehicleParams()) as rig:
        _hovering(rig)
        t0 = rig.clock.now()
        rig.quad.armed = False  # e.g. a pilot's kill switch
        r = _wait_release(rig)
        assert r is not None and r.code == "disarmed"
        assert r.t - t0 <= HB_BOUND
        _nothing_commanded_after(rig, ARDUPILOT_MODES["GUIDED_NOGPS"])


def test_critical_battery_lands_in_our_mode() -> None:
    """Battery at 10 % (≤ 15 %) while in GUIDED_NOGPS: leave, and land with the autopilot's
    LAND (the one command still ours to give)."""
    with FlightRig(VehicleParams()) as rig:
        _hovering(rig)
        t0 = rig.clock.now()
        rig.fleet.state.consumed[0] = 0.9 * rig.fleet.params[0].battery_mah
        r = _wait_release(rig)
        assert r is not None and r.code == "battery_critical", r
        assert r.t - t0 <= HB_BOUND
        assert wait_until(lambda: rig.quad.mode == ARDUPILOT_MODES["LAND"], 3.0)
        assert wait_until(lambda: not rig.quad.armed, 15.0)


def test_link_loss_is_detected_within_the_bound() -> None:
    with FlightRig(VehicleParams()) as rig:
        _hovering(rig)
        t_cut = rig.clock.now()
        rig.quad.link.write = lambda _buf: None
        r = _wait_release(rig)
        mon = rig.driver.monitor
        assert r is not None and r.code == "link_lost" and mon is not None
        assert mon.last_heartbeat is not None and 3.0 <= r.t - mon.last_heartbeat <= 3.3
        assert r.t - t_cut <= LINK_BOUND
        time.sleep(0.2)
        before = rig.quad.log.setpoints
        rig.run_for(1.0)
        assert rig.quad.log.setpoints == before and not rig.driver.streaming


def test_command_ack_to_another_system_is_not_ours(monkeypatch: pytest.MonkeyPatch) -> None:
    """The vehicle does not answer our DO_SET_MODE; a ground station's identical command is
    accepted (and the HEARTBEAT shows the mode), but its ACK is addressed to system 255: the
    driver must not take it."""
    with FlightRig(VehicleParams(), cfg=DriverConfig(ack_timeout_s=0.6)) as rig:
        real = rig.quad._handle

        def deaf_to_us(msg: Any, t: float) -> None:
            if msg.get_type() == "COMMAND_LONG" and msg.get_srcComponent() == 191:
                return
            real(msg, t)

        monkeypatch.setattr(rig.quad, "_handle", deaf_to_us)
        gcs = _pilot(rig)
        try:
            def gcs_sets_mode() -> None:
                gcs.mav.command_long_send(1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0,
                                          mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 20,
                                          0, 0, 0, 0, 0)

            gcs_sets_mode()
            acks = []
            assert wait_until(lambda: rig.quad.mode == 20, 3.0)
            with pytest.raises(FlightError, match="no COMMAND_ACK"):
                for _ in range(3):
                    gcs_sets_mode()  # ACKs to 255/190 keep arriving on our link
                rig.driver.set_mode(20)
            acks.append(gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=2.0))
            assert acks[0] is not None and acks[0].target_system == 255
        finally:
            gcs.close()


def test_failed_engage_leaves_no_setpoint_stream() -> None:
    """PX4 refuses OFFBOARD (COM_OF_LOSS_T 0: no set-point is ever fresh enough): engage
    raises and the stream stops."""
    params = VehicleParams(autopilot="px4", params={"COM_OF_LOSS_T": 0.0})
    cfg = DriverConfig(autopilot="px4", ack_timeout_s=0.5, mocap_stale_s=0.5)
    with FlightRig(params, cfg=cfg) as rig:
        with pytest.raises(FlightError, match="refused"):
            rig.driver.engage()
        assert not rig.driver.streaming and rig.driver.phase == "idle"
        time.sleep(0.2)
        before = rig.quad.log.setpoint_times[-1] if rig.quad.log.setpoint_times else 0.0
        time.sleep(0.5)
        after = rig.quad.log.setpoint_times[-1] if rig.quad.log.setpoint_times else 0.0
        assert after == before and not rig.quad.armed


# -- pre-flight -------------------------------------------------------------------------------

def test_px4_int32_parameters_are_decoded_bytewise() -> None:
    wire = float(np.frombuffer(np.int32(11).tobytes(), dtype=np.float32)[0])
    assert wire < 1e-40  # what a float reader would see
    assert decode_param_value(wire, mavlink.MAV_PARAM_TYPE_INT32, bytewise=True) == 11.0
    assert decode_param_value(6.0, mavlink.MAV_PARAM_TYPE_INT8, bytewise=False) == 6.0
    assert decode_param_value(0.5, mavlink.MAV_PARAM_TYPE_REAL32, bytewise=True) == 0.5


@pytest.mark.parametrize(("autopilot", "wrong", "param"), [
    ("ardupilot", {"VISO_TYPE": 0}, "VISO_TYPE"),
    ("ardupilot", {"EK3_SRC1_YAW": 1}, "EK3_SRC1_YAW"),
    ("px4", {"EKF2_EV_CTRL": 3}, "EKF2_EV_CTRL"),
    ("px4", {"EKF2_HGT_REF": 1}, "EKF2_HGT_REF"),
    ("px4", {"COM_OBL_RC_ACT": 3}, "COM_OBL_RC_ACT"),
])
def test_preflight_refuses_a_wrongly_configured_autopilot(autopilot: str, wrong: dict[str, float],
                                                         param: str) -> None:
    good = VehicleParams(autopilot=autopilot, indoor=True, hover_thrust=0.42)
    bad = VehicleParams(autopilot=autopilot, indoor=True, params=wrong)
    cfg = DriverConfig(autopilot=autopilot, ack_timeout_s=0.3)
    with FlightRig(good, cfg=cfg) as rig:
        rep = check_autopilot(rig.driver, 0.5)
        assert rep.fatal == [] and rep.refusal() == ""
        assert rep.hover_seed == pytest.approx(0.42)
        assert rep.hover_source == ("MOT_THST_HOVER" if autopilot == "ardupilot"
                                    else "MPC_THR_HOVER")
        if autopilot == "px4":
            assert rep.params["EKF2_EV_CTRL"] == 11.0  # int32, sent byte-wise
    with FlightRig(bad, cfg=cfg) as rig:
        rep = check_autopilot(rig.driver, 0.5)
        assert [p.param for p in rep.fatal] == [param]
        line = rep.refusal()
        assert line.startswith(f"pre-flight: {param} = ") and "\n" not in line
        assert not rig.quad.armed and rig.quad.log.setpoints == 0


def test_preflight_command(capsys: pytest.CaptureFixture[str]) -> None:
    from agent.clock import WallClock
    from groundstation.vehicle.fleet import SimFleet

    with SimFleet(["A"], WallClock(), VehicleParams(autopilot="px4", indoor=True)) as ok, \
            SimFleet(["A"], WallClock(), VehicleParams(indoor=False)) as fresh:
        ok.start()
        fresh.start()
        assert main(["preflight", "--mavlink", f"udpout:127.0.0.1:{ok.quads[0].port}"]) == 0
        out = capsys.readouterr().out
        assert "viscover-preflight ok: px4 system 1" in out
        assert main(["preflight", "--mavlink", f"udpout:127.0.0.1:{fresh.quads[0].port}",
                     "--autopilot", "ardupilot"]) == 1
        lines = capsys.readouterr().out.splitlines()
        assert lines[-1].startswith("viscover-preflight refused: pre-flight: VISO_TYPE = 0")
        assert any(x.startswith("EK3_SRC1_POSXY = 3, needs 6") for x in lines)
        assert main(["preflight", "--mavlink", f"udpout:127.0.0.1:{ok.quads[0].port}",
                     "--autopilot", "ardupilot"]) == 2
        assert "HEARTBEAT says px4" in capsys.readouterr().err
    assert main(["preflight", "--mavlink", "udpout:127.0.0.1:9", "--timeout", "0.3"]) == 1


# -- serial -----------------------------------------------------------------------------------

def test_serial_connection_string_reaches_a_mavlink_peer() -> None:
    """``/dev/pts/N,921600`` (pyserial) through a pseudo-terminal pair: our HEARTBEAT arrives
    at the other end, the peer's HEARTBEAT reaches the driver."""
    import tty

    from agent.clock import WallClock
    from agent.flight.controllers import FlightController
    from agent.flight.mavlink_driver import MavlinkDriver

    master, slave = os.openpty()
    tty.setraw(master)
    name = os.ttyname(slave)
    peer = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    drv = MavlinkDriver(f"{name},921600", lambda: None, FlightController(),
                        DriverConfig(heartbeat_timeout_s=3.0), WallClock())
    try:
        drv.start()
        os.set_blocking(master, False)
        got: list[Any] = []

        def read_peer() -> bool:
            try:
                data = os.read(master, 4096)
            except BlockingIOError:
                return False
            got.extend(peer.parse_buffer(data) or [])
            return any(m.get_type() == "HEARTBEAT" for m in got)

        assert wait_until(read_peer, 5.0)
        hb = next(m for m in got if m.get_type() == "HEARTBEAT")
        assert hb.type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER
        vehicle_hb = peer.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR,
                                           mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 20,
                                           mavlink.MAV_STATE_STANDBY).pack(peer)
        assert wait_until(lambda: os.write(master, vehicle_hb) > 0
                          and drv.vehicle.heartbeat_wall > 0, 5.0, poll_s=0.2)
        assert drv.target_system == 1 and drv.vehicle.custom_mode == 20
    finally:
        drv.close()
        os.close(master)
        os.close(slave)


# -- MAVProxy as the pilot ------------------------------------------------------------------

def test_mavproxy_pilot_takes_over(tmp_path: Any) -> None:
    """MAVProxy (a real ground station, the ``test`` extras) on the simulated vehicle's link
    switches to LOITER while the driver flies: the driver lets go within the HEARTBEAT bound
    and never switches back."""
    import shutil
    import subprocess
    import threading

    exe = shutil.which("mavproxy.py") or str(Path(sys.executable).with_name("mavproxy.py"))
    with FlightRig(VehicleParams(indoor=True)) as rig:
        _hovering(rig)
        proc = subprocess.Popen(
            [exe, f"--master=udpout:127.0.0.1:{rig.quad.port}", "--default-modules=mode",
             "--source-system=255"], cwd=tmp_path, stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        lines: list[str] = []
        reader = threading.Thread(target=lambda: lines.extend(proc.stdout or []), daemon=True)
        reader.start()
        try:
            assert wait_until(lambda: any("Detected vehicle 1:1" in x for x in lines), 20.0), \
                lines
            assert proc.stdin is not None
            t0 = rig.clock.now()
            proc.stdin.write("mode LOITER\n")
            proc.stdin.flush()
            r = _wait_release(rig)
            assert r is not None and r.code == "mode_changed" and "LOITER" in r.reason
            assert r.t - t0 <= HB_BOUND + 0.3  # + MAVProxy's own command latency
            _nothing_commanded_after(rig, ARDUPILOT_MODES["LOITER"])
            assert wait_until(lambda: any("DO_SET_MODE: ACCEPTED" in x for x in lines), 5.0)
        finally:
            stop_process(proc, reader)
