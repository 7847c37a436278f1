"""WGS-84 geodesy of agent.flight.geodetic: round trips, the textbook lengths of a degree, ECEF
reference points and compass headings."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.flight.geodetic import (
    WGS84_A,
    WGS84_E2,
    WGS84_F,
    Origin,
    compass_heading,
    ecef_to_geodetic,
    enu_to_geodetic,
    geodetic_to_ecef,
    geodetic_to_enu,
)


def test_round_trip_geodetic_enu_geodetic() -> None:
    rng = np.random.default_rng(3)
    for lat0, lon0, alt0 in [(45.0, 7.0, 300.0), (-33.9, 151.2, 20.0), (89.9, -120.0, 0.0),
                             (0.0, 179.99, -50.0), (64.1, -21.9, 1200.0)]:
        origin = Origin(lat0, lon0, alt0)
        lat = lat0 + rng.uniform(-0.01, 0.01, 50)
        lon = lon0 + rng.uniform(-0.01, 0.01, 50)
        alt = alt0 + rng.uniform(-100.0, 500.0, 50)
        enu = geodetic_to_enu(lat, lon, alt, origin)
        lat2, lon2, alt2 = enu_to_geodetic(enu, origin)
        assert np.max(np.abs(lat2 - lat)) < 1e-9
        assert np.max(np.abs(((lon2 - lon) + 180.0) % 360.0 - 180.0)) < 1e-9
        assert np.max(np.abs(alt2 - alt)) < 1e-6


def test_round_trip_enu_geodetic_enu() -> None:
    origin = Origin(47.3977419, 8.545594, 488.0)
    enu = np.random.default_rng(4).uniform(-2000.0, 2000.0, (100, 3))
    back = geodetic_to_enu(*enu_to_geodetic(enu, origin), origin)
    assert np.max(np.abs(back - enu)) < 1e-6


def test_one_metre_north_and_east_at_45_degrees() -> None:
    """1 m north is 1/111,132 degree of latitude at 45°, 1 m east 1/(111,320 cos 45°) degree of
    longitude (the usual approximations); exactly 1/(π/180 M) and 1/(π/180 N cos φ) with the
    meridian and prime-vertical radii M and N."""
    origin = Origin(45.0, 7.0, 0.0)
    lat, lon, _ = enu_to_geodetic(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]), origin)
    dlat, dlon = lat[0] - 45.0, lon[1] - 7.0
    assert dlat == pytest.approx(1.0 / 111132.0, rel=1e-4)
    assert dlon == pytest.approx(1.0 / (111320.0 * math.cos(math.radians(45.0))), rel=3e-3)
    s2 = math.sin(math.radians(45.0)) ** 2
    m = WGS84_A * (1 - WGS84_E2) / (1 - WGS84_E2 * s2) ** 1.5
    n = WGS84_A / math.sqrt(1 - WGS84_E2 * s2)
    assert dlat == pytest.approx(1.0 / (math.pi / 180 * m), rel=1e-6)
    assert dlon == pytest.approx(1.0 / (math.pi / 180 * n * math.cos(math.radians(45.0))),
                                 rel=1e-6)
    assert lat[1] - 45.0 == pytest.approx(0.0, abs=1e-12)  # east stays on the parallel
    assert lon[0] - 7.0 == pytest.approx(0.0, abs=1e-12)


def test_ecef_reference_points() -> None:
    b = WGS84_A * (1.0 - WGS84_F)
    assert np.allclose(geodetic_to_ecef(0.0, 0.0, 0.0), [WGS84_A, 0.0, 0.0])
    assert np.allclose(geodetic_to_ecef(0.0, 90.0, 10.0), [0.0, WGS84_A + 10.0, 0.0])
    assert np.allclose(geodetic_to_ecef(90.0, 0.0, 0.0), [0.0, 0.0, b], atol=1e-6)
    lat, lon, h = ecef_to_geodetic([0.0, 0.0, b + 5.0])
    assert float(lat) == pytest.approx(90.0) and float(h) == pytest.approx(5.0, abs=1e-6)
    lat, lon, h = ecef_to_geodetic([WGS84_A + 100.0, 0.0, 0.0])
    assert (float(lat), float(lon), float(h)) == pytest.approx((0.0, 0.0, 100.0))


def test_up_is_the_ellipsoid_normal() -> None:
    origin = Origin(30.0, -60.0, 100.0)
    lat, lon, alt = enu_to_geodetic([0.0, 0.0, 25.0], origin)
    assert (float(lat), float(lon), float(alt)) == pytest.approx((30.0, -60.0, 125.0))


def test_compass_heading() -> None:
    assert compass_heading(0.0, 1.0) == 0.0
    assert compass_heading(1.0, 0.0) == pytest.approx(90.0)
    assert compass_heading(0.0, -1.0) == pytest.approx(180.0)
    assert compass_heading(-1.0, 0.0) == pytest.approx(270.0)
    assert 0.0 <= compass_heading(-1e-17, 1.0) < 360.0
    assert math.isnan(compass_heading(0.0, 0.0))


@pytest.mark.parametrize("bad", [(91.0, 0.0, 0.0), (0.0, 181.0, 0.0), (math.nan, 0.0, 0.0)])
def test_origin_is_checked(bad: tuple[float, float, float]) -> None:
    with pytest.raises(ValueError):
        Origin(*bad)
