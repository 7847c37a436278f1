"""The simulated EKF outdoors: GNSS-aided estimates with seeded noise and drift
(:mod:`groundstation.vehicle.ekf`), selected as the autopilots select their position source
(ArduPilot EK3_SRC1_POSXY, libraries/AP_NavEKF/AP_NavEKF_Source.cpp; PX4 EKF2_GPS_CTRL /
EKF2_EV_CTRL, src/modules/ekf2/params_*.yaml), and what it streams."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.flight.frames import quat_is_unit
from agent.wire.mavlink import ARDUPILOT_MODES as APM
from groundstation.vehicle.conventions import ORIGIN
from groundstation.vehicle.ekf import GnssEkf, GnssModel
from groundstation.vehicle.params import VehicleParams
from tests.sim_vehicle_helpers import M, hello, result
from tests.vehicle_harness import Harness

REQ = M.MAV_CMD_REQUEST_MESSAGE


def test_drift_is_gauss_markov_with_the_stated_magnitude_and_seeded() -> None:
    """Stationary 1σ drift_h / drift_v, correlation exp(−Δ/τ), and a realisation that depends
    only on the seed and the time (not on how often it is read)."""
    model = GnssModel.preset("rtk")
    ekf = GnssEkf(model, (7, 0))
    taus = np.arange(1, 4001) * model.drift_tau  # samples one τ apart
    d = np.array([ekf.drift(float(t)) for t in taus])
    assert np.std(d[:, 0]) == pytest.approx(model.drift_h, rel=0.1)
    assert np.std(d[:, 2]) == pytest.approx(model.drift_v, rel=0.1)
    lag1 = np.corrcoef(d[:-1, 0], d[1:, 0])[0, 1]
    assert lag1 == pytest.approx(math.exp(-1.0), abs=0.05)
    a, b = GnssEkf(model, (3, 1)), GnssEkf(model, (3, 1))
    for t in np.arange(0.0, 100.0, 0.05):
        a.drift(float(t))
    assert np.allclose(a.drift(100.0), b.drift(100.0), atol=1e-12)
    assert not np.allclose(GnssEkf(model, (4, 1)).drift(100.0), b.drift(100.0))


def test_presets_and_overrides() -> None:
    rtk, gnss3d = GnssModel.preset("rtk"), GnssModel.preset("3d")
    assert rtk.fix_type == M.GPS_FIX_TYPE_RTK_FIXED and gnss3d.fix_type == M.GPS_FIX_TYPE_3D_FIX
    assert gnss3d.drift_h > 10 * rtk.drift_h
    assert GnssModel.preset("rtk", {"drift_h": 0.0}).drift_h == 0.0
    with pytest.raises(ValueError, match="unknown gnss_noise"):
        GnssModel.preset("rtk", {"nope": 1.0})
    with pytest.raises(ValueError, match=">= 0"):
        GnssModel.preset("rtk", {"pos_noise_h": -1.0})
    with pytest.raises(ValueError, match="gnss must be"):
        VehicleParams(gnss="dgps")


def _errors(h: Harness, seconds: float) -> np.ndarray:
    """LOCAL_POSITION_NED minus the truth [m] over ``seconds`` of flight on the ground."""
    out = []
    end = h.clock.now() + seconds
    while h.clock.now() < end:
        h.run(0.1)
        for m in h.of("LOCAL_POSITION_NED"):
            out.append([m.x, m.y, m.z] - h.fleet.p[0])
    return np.array(out)


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_rtk_vehicle_has_a_position_without_mocap_and_reports_rtk_fixed(autopilot: str) -> None:
    """A GNSS receiver and the flavour's default source (GPS): position without mocap, so
    position modes arm; GPS_RAW_INT RTK fixed; estimates within centimetres, not exact."""
    with hello(Harness(VehicleParams(autopilot=autopilot, gnss="rtk"), seed=5)) as h:
        err = _errors(h, 3.0)
        assert len(err) > 50
        assert np.all(np.abs(err) < 0.15) and np.std(err[:, 0]) > 0.002
        gps = h.wait_for("GPS_RAW_INT", sim_s=0.5)
        assert gps.fix_type == M.GPS_FIX_TYPE_RTK_FIXED and gps.satellites_visible == 24
        assert gps.h_acc < 50 and gps.eph == 70  # mm, HDOP x 100
        lat0, lon0, alt0 = ORIGIN[autopilot]
        assert gps.lat == pytest.approx(lat0 * 1e7, abs=10)
        assert gps.lon == pytest.approx(lon0 * 1e7, abs=15)
        assert gps.alt == pytest.approx(alt0 * 1000, abs=150)
        assert result(h, REQ, M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN) == M.MAV_RESULT_ACCEPTED
        origin = h.wait_for("GPS_GLOBAL_ORIGIN")
        assert (origin.latitude, origin.altitude) == (round(lat0 * 1e7), round(alt0 * 1000))
        mode = 5 if autopilot == "ardupilot" else None  # LOITER / POSCTL need a position
        if mode is not None:
            assert h.set_mode(APM["LOITER"]) == M.MAV_RESULT_ACCEPTED
        else:
            assert h.set_mode(3 << 16) == M.MAV_RESULT_ACCEPTED  # POSCTL
        assert h.arm() == M.MAV_RESULT_ACCEPTED
        assert h.fleet.handler_errors == 0


def test_3d_fix_is_metres_off_and_the_same_seed_gives_the_same_estimates() -> None:
    def run(seed: int) -> np.ndarray:
        with hello(Harness(VehicleParams(gnss="3d"), seed=seed)) as h:
            return _errors(h, 2.0)

    a, b, c = run(11), run(11), run(12)
    assert np.array_equal(a, b)  # seeded: the same run twice
    assert not np.array_equal(a, c)
    assert float(np.max(np.abs(a[:, :2]))) > 0.2  # a 3-D fix wanders by decimetres to metres
    gps_model = GnssModel.preset("3d")
    assert float(np.std(a[:, 0] - np.mean(a[:, 0]))) == \
        pytest.approx(gps_model.pos_noise_h, rel=0.4)  # the white part over 2 s


def test_no_receiver_or_external_navigation_selected_means_no_position() -> None:
    with hello(Harness(VehicleParams())) as h:  # no GNSS receiver, no mocap
        assert h.set_mode(APM["LOITER"]) == M.MAV_RESULT_ACCEPTED
        assert h.arm() == M.MAV_RESULT_FAILED  # Need Position Estimate
        assert result(h, REQ, M.MAVLINK_MSG_ID_GPS_RAW_INT) == M.MAV_RESULT_UNSUPPORTED
    with hello(Harness(VehicleParams(gnss="rtk", indoor=True))) as h:  # EK3_SRC1_POSXY 6
        assert h.set_mode(APM["LOITER"]) == M.MAV_RESULT_ACCEPTED
        assert h.arm() == M.MAV_RESULT_FAILED  # selected external navigation, none heard
        h.every = h.vision
        h.run(0.3)
        assert h.arm() == M.MAV_RESULT_ACCEPTED
        err = _errors(h, 1.0)
        assert np.all(np.abs(err) < 1e-9)  # mocap source: the truth (no sensor noise set)


def test_px4_odometry_on_request() -> None:
    with hello(Harness(VehicleParams(autopilot="px4", gnss="rtk"))) as h:
        # In the air, heading east, moving north at 1 m/s: EKF2's odometry is NED throughout
        # (src/modules/mavlink/streams/ODOMETRY.hpp: child frame from velocity_frame).
        h.fleet.p[0] = [0.0, 0.0, -20.0]
        h.fleet.att[0] = [0.0, 0.0, math.pi / 2]
        h.fleet.v[0] = [1.0, 0.0, 0.0]
        assert result(h, REQ, M.MAVLINK_MSG_ID_ODOMETRY) == M.MAV_RESULT_ACCEPTED
        odo = h.wait_for("ODOMETRY")
        assert (odo.frame_id, odo.child_frame_id) == (M.MAV_FRAME_LOCAL_NED, M.MAV_FRAME_LOCAL_NED)
        assert quat_is_unit(odo.q) and odo.estimator_type == M.MAV_ESTIMATOR_TYPE_AUTOPILOT
        assert odo.z == pytest.approx(-20.0, abs=0.5)
        assert odo.vx == pytest.approx(1.0, abs=0.1) and abs(odo.vy) < 0.1
        rtk = GnssModel.preset("rtk")
        assert odo.pose_covariance[0] == pytest.approx(rtk.pos_noise_h**2 + rtk.drift_h**2)
        assert math.isnan(odo.pose_covariance[1]) and math.isnan(odo.velocity_covariance[1])
    with hello(Harness(VehicleParams())) as h:
        assert result(h, REQ, M.MAVLINK_MSG_ID_ODOMETRY) == M.MAV_RESULT_UNSUPPORTED
