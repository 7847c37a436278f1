"""Fences (agent.flight.fence, agent.flight.mission_protocol): the mission space less a margin
as an inclusion polygon with an altitude limit and the structure as an exclusion polygon,
uploaded to ArduPilot (MISSION_REQUEST) and PX4 (MISSION_REQUEST_INT) with the mission
protocol and read back; a refused upload and a corrupted read-back in one line; the
pre-flight fence rules; breaches as each autopilot reports them; and the set-point
streamer's space guard."""

from __future__ import annotations

import logging
from collections.abc import Iterator

import numpy as np
import pytest

from agent.clock import WallClock
from agent.flight.autopilot_check import check_autopilot
from agent.flight.controllers import FlightConfig, FlightController
from agent.flight.driver_types import DriverConfig, FlightError, PoseSample
from agent.flight.fence import FenceBreach, FenceClient, FenceMonitor, fence_plan
from agent.flight.geodetic import Origin, geodetic_to_enu
from agent.flight.mavlink_driver import MavlinkDriver
from agent.flight.mission_protocol import MissionItem, MissionTransfer
from agent.flight.preflight import fence_problems
from agent.wire.mavlink import mavlink
from tests.conftest import wait_until
from tests.flight_peer import Peer

ORIGIN = Origin(47.397742, 8.545594, 488.0)
LO, HI = (-20.0, -15.0, 0.0), (30.0, 25.0, 18.0)
STRUCTURE = (np.array([0.0, 0.0, 0.0]), np.array([20.0, 12.0, 10.0]))


def test_plan_is_the_space_less_the_margin() -> None:
    plan = fence_plan(LO, HI, ORIGIN, margin=2.0, structure=STRUCTURE)
    lat, lon = zip(*plan.inclusion, strict=True)
    enu = geodetic_to_enu(np.array(lat), np.array(lon), np.full(4, ORIGIN.alt), ORIGIN)
    np.testing.assert_allclose(enu[:, :2], [[-18, -13], [28, -13], [28, 23], [-18, 23]],
                               atol=0.01)
    assert plan.alt_max_m == 16.0 and plan.lo == (-18.0, -13.0, 2.0)
    assert plan.alt_above_home(home_z=1.5) == 14.5
    items = plan.items()
    assert [it.command for it in items] == [5001] * 4 + [5002] * 4
    assert {it.param1 for it in items} == {4.0}
    assert items[0].frame == mavlink.MAV_FRAME_GLOBAL
    assert fence_plan(LO, HI, ORIGIN, structure=STRUCTURE, exclude_structure=False).exclusion == ()
    with pytest.raises(ValueError, match="a margin of 30 m leaves no space"):
        fence_plan(LO, HI, ORIGIN, margin=30.0)
    with pytest.raises(ValueError, match="structure's bounding box reaches the fence"):
        fence_plan(LO, HI, ORIGIN, margin=2.0, structure=(np.zeros(3), np.array([29, 5, 5])))


@pytest.fixture(params=["ardupilot", "px4"])
def rig(request: pytest.FixtureRequest) -> Iterator[tuple[Peer, MavlinkDriver]]:
    cfg = DriverConfig(autopilot=request.param, ack_timeout_s=0.3, forward="none")
    with Peer(request.param) as peer, \
            MavlinkDriver(peer.conn_str, lambda: None, FlightController(), cfg,
                          WallClock()) as drv:
        drv.wait_heartbeat()
        yield peer, drv


def test_install_uploads_reads_back_and_sets_the_altitude(rig: tuple[Peer, MavlinkDriver]
                                                          ) -> None:
    peer, drv = rig
    plan = fence_plan(LO, HI, ORIGIN, margin=2.0, structure=STRUCTURE)
    fence = FenceClient(drv.link, drv.params)
    fence.install(plan, home_z=1.0)
    stored = [(int(m.command), int(m.x), int(m.y), float(m.param1)) for m in peer.fence]
    assert stored == [(it.command, it.x, it.y, it.param1) for it in plan.items()]
    assert len(peer.received("MISSION_COUNT")) == 1  # answered at once: never resent
    assert len(peer.received("MISSION_ITEM_INT")) == len(plan.items())
    assert len(peer.received("MISSION_ACK")) == 1  # ours, closing the read-back
    if peer.px4:
        assert peer.params["GF_MAX_VER_DIST"] == pytest.approx(15.0)
    else:
        assert peer.params["FENCE_ALT_MAX"] == pytest.approx(15.0)
        assert int(peer.params["FENCE_TYPE"]) & 5 == 5  # polygon + max altitude enforced
    fence.close()


def test_refused_upload_and_corrupted_read_back(rig: tuple[Peer, MavlinkDriver],
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    peer, drv = rig
    transfer = MissionTransfer(drv.link, mavlink.MAV_MISSION_TYPE_FENCE)
    bad = [MissionItem(5001, 1, 2, param1=1.0, frame=mavlink.MAV_FRAME_LOCAL_NED)]
    with pytest.raises(FlightError, match="refused: MAV_MISSION_UNSUPPORTED_FRAME"):
        transfer.upload(bad)
    transfer.close()
    fence = FenceClient(drv.link, drv.params)
    real_store = peer._on_mission_item_int

    def corrupt(msg: object) -> None:
        real_store(msg)
        if peer.fence:
            peer.fence[-1].x += 100  # the vehicle stored another vertex

    monkeypatch.setattr(peer, "_on_mission_item_int", corrupt)
    with pytest.raises(FlightError, match="fence read back differs at item 3"):
        fence.install(fence_plan(LO, HI, ORIGIN))
    fence.close()


def test_preflight_fence_rules(rig: tuple[Peer, MavlinkDriver]) -> None:
    peer, drv = rig
    assert fence_problems("ardupilot", {"FENCE_ENABLE": 1, "FENCE_ACTION": 4,
                                        "FENCE_TYPE": 7}) == []
    got = fence_problems("ardupilot", {"FENCE_ENABLE": 0, "FENCE_ACTION": 0, "FENCE_TYPE": 2})
    assert [(p.param, p.fatal) for p in got] == [("FENCE_ENABLE", True),
                                                  ("FENCE_ACTION", True), ("FENCE_TYPE", False)]
    assert [p.param for p in fence_problems("px4", {"GF_ACTION": 1})] == ["GF_ACTION"]
    if peer.px4:
        peer.params["GF_ACTION"] = 0
    else:
        peer.params["FENCE_ENABLE"] = 0
    report = check_autopilot(drv, 0.5, pose="autopilot", fence=True)
    fatal = [p.param for p in report.fatal]
    assert fatal == (["GF_ACTION"] if peer.px4 else ["FENCE_ENABLE"])  # no mocap rules
    assert "EK3_SRC1_POSXY" not in report.params and "EKF2_EV_CTRL" not in report.params


def test_breaches_as_each_autopilot_reports_them(rig: tuple[Peer, MavlinkDriver]) -> None:
    peer, drv = rig
    got: list[FenceBreach] = []
    mon = FenceMonitor(drv.link, got.append)
    if peer.px4:  # a failsafe announced in a STATUSTEXT (no FENCE_STATUS on PX4)
        for _ in range(3):
            peer.statustext("Geofence violation: Hold")
        peer.statustext("Preflight check: all good", mavlink.MAV_SEVERITY_INFO)
    else:
        peer.fence_breach = (1, 1, 3)  # FENCE_STATUS: breached, count 1, boundary
    assert wait_until(lambda: len(got) >= 1, 3.0)
    assert wait_until(lambda: mon.breached, 1.0)
    b = got[0]
    assert (b.source, b.kind) == (("STATUSTEXT", "unknown") if peer.px4 else
                                  ("FENCE_STATUS", "boundary"))
    if not peer.px4:
        peer.fence_breach = (1, 2, 2)  # a second breach, max altitude
        assert wait_until(lambda: len(got) == 2 and got[1].kind == "max_alt", 3.0)
    assert len(mon.breaches) == len(got) == (1 if peer.px4 else 2)  # repeats not reported
    mon.close()


def test_streamer_clamps_a_target_outside_the_space(caplog: pytest.LogCaptureFixture) -> None:
    clock = WallClock()

    def pose() -> PoseSample:
        return PoseSample(clock.now(), np.array([0.0, 0.0, 1.0]), np.zeros(3),
                          np.array([1.0, 0.0, 0.0, 0.0]), 0.0)

    ctl = FlightController(FlightConfig(lo=(-50, -50, 0), hi=(50, 50, 30), margin=0.5))
    with Peer("ardupilot") as peer:
        drv = MavlinkDriver(peer.conn_str, pose, ctl, DriverConfig(forward="none"), clock)
        try:
            ctl.set_hold([40.0, 0.0, 25.0], 0.0)  # inside the controller's walls ...
            plan = fence_plan(LO, HI, ORIGIN, margin=2.0)
            drv.streamer.set_space(plan.lo, plan.hi)  # ... not inside the fence's
            drv.streaming, drv.phase = True, "flying"
            with caplog.at_level(logging.WARNING):
                drv._step()
                drv._step()
            assert ctl.p_hold is not None
            np.testing.assert_allclose(ctl.p_hold, [27.5, 0.0, 15.5])
            assert drv.stats.clamped == 1 and caplog.text.count("outside the space") == 1
            ctl.set_velocity([0.0, 0.0, 5.0], 0.0)  # velocities are braked at the new walls
            assert np.asarray(ctl.cfg.hi)[2] == 16.0
        finally:
            drv.close()


def test_preflight_command_checks_the_fence(capsys: pytest.CaptureFixture[str]) -> None:
    """``viscover preflight --pose autopilot --fence``: the fence rules, no mocap rules, the
    battery line; a disabled fence refuses."""
    from agent.cli import main

    with Peer("ardupilot") as peer:
        argv = ["preflight", "--mavlink", peer.conn_str, "--pose", "autopilot", "--fence"]
        assert main(argv) == 0
        out = capsys.readouterr().out.splitlines()
        assert any(x.startswith("FENCE_TYPE = 2, needs bits 1 and 4") for x in out)
        assert not any(x.startswith(("VISO_TYPE", "EK3_SRC1")) for x in out)
        assert out[-1].startswith("viscover-preflight ok: ardupilot system 1")
        peer.params["FENCE_ENABLE"] = 0
        assert main(argv) == 1
        out = capsys.readouterr().out.splitlines()
        assert out[-1].startswith("viscover-preflight refused: pre-flight: FENCE_ENABLE = 0")


def test_fly_pose_flags_reach_the_runner_or_refuse_in_one_line() -> None:
    import argparse

    from agent.commands.fly import field_options
    from agent.errors import UsageError
    from agent.runners.flying import FlightOptions

    ns = argparse.Namespace
    assert field_options(ns(pose="mocap", origin=None)) == {"pose": "mocap", "origin": None}
    with pytest.raises(UsageError, match="--origin goes with --pose autopilot"):
        field_options(ns(pose="mocap", origin=ORIGIN))
    opts = FlightOptions(**field_options(ns(pose="autopilot", origin=ORIGIN)))
    assert (opts.pose, opts.origin) == ("autopilot", ORIGIN)
