"""``viscover export-images``: an inspection run's images as ``images.csv``, OpenDroneMap's
``geo.txt`` and ``captures.geojson`` (agent.mission.images, agent.commands.images), checked
against the logged captures with code of the test's own: geo.txt read back the way ODM's
``opendm/geo.py`` reads it, WGS-84 by a closed-form ECEF inversion (Heikkinen), ODM's own
yaw-pitch-roll rotation (``opendm/photo.py`` ``compute_opk``), GSD written out."""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
import statistics
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agent.cli import main
from agent.core.camera import Camera
from agent.mission.images import image_records, images_csv
from tests.conftest import ROOT, scenario_path

#: lat, lon [deg], alt [m] of the world frame's origin in these tests.
ORIGIN = (47.3977, 8.5456, 488.0)
ORIGIN_ARG = ",".join(str(v) for v in ORIGIN)

# WGS-84 (NIMA TR8350.2), written out here rather than taken from agent.flight.geodetic.
A = 6378137.0
F = 1.0 / 298.257223563
B = A * (1.0 - F)
E2 = F * (2.0 - F)
EP2 = (A * A - B * B) / (B * B)


def viscover(*args: str) -> subprocess.CompletedProcess[str]:
    """``viscover ARGS`` run in this process from the checkout (the function the command
    runs: these tests check what it writes and says, not its process): its exit status,
    stdout and stderr."""
    out, err = io.StringIO(), io.StringIO()
    here = Path.cwd()
    os.chdir(ROOT)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            status = main(list(args))
    finally:
        os.chdir(here)
    return subprocess.CompletedProcess(["viscover", *args], status, out.getvalue(),
                                       err.getvalue())


@dataclass(frozen=True)
class Export:
    """One simulated inspection and what export-images made of it."""

    doc: dict[str, Any]
    geo_dir: Path
    geo_stdout: str
    plain_dir: Path
    plain_stdout: str


@pytest.fixture(scope="module")
def export(tmp_path_factory: pytest.TempPathFactory) -> Export:
    """``viscover simulate`` of the gabled house once, then ``export-images`` with and
    without an origin."""
    base = tmp_path_factory.mktemp("images")
    run = base / "run"
    sim = viscover("simulate", str(scenario_path("inspect_gabled_house")), "--out", str(run),
                   "--no-plots")
    assert sim.returncode == 0, sim.stderr
    geo = viscover("export-images", str(run), "--out", str(base / "geo"), "--origin",
                   ORIGIN_ARG)
    assert geo.returncode == 0, geo.stderr
    plain = viscover("export-images", str(run), "--out", str(base / "plain"))
    assert plain.returncode == 0, plain.stderr
    doc = json.loads((run / "result.json").read_text(encoding="utf-8"))
    assert len(doc["captures"]) >= 10
    return Export(doc, base / "geo", geo.stdout, base / "plain", plain.stdout)


# -- the test's own geodesy and ODM's own reading ----------------------------------------------


def ecef(lat: float, lon: float, h: float) -> np.ndarray:
    """ECEF [m] of a geodetic point (degrees, metres)."""
    phi, lam = math.radians(lat), math.radians(lon)
    n = A / math.sqrt(1.0 - E2 * math.sin(phi) ** 2)
    return np.array([(n + h) * math.cos(phi) * math.cos(lam),
                     (n + h) * math.cos(phi) * math.sin(lam),
                     (n * (1.0 - E2) + h) * math.sin(phi)])


def geodetic(xyz: np.ndarray) -> tuple[float, float, float]:
    """Latitude, longitude [deg] and height [m] of an ECEF point: Heikkinen's closed form
    (no iteration)."""
    x, y, z = (float(v) for v in xyz)
    p = math.hypot(x, y)
    f = 54.0 * B * B * z * z
    g = p * p + (1.0 - E2) * z * z - E2 * (A * A - B * B)
    c = E2 * E2 * f * p * p / g ** 3
    s = (1.0 + c + math.sqrt(c * c + 2.0 * c)) ** (1.0 / 3.0)
    k = s + 1.0 + 1.0 / s
    pp = f / (3.0 * k * k * g * g)
    q = math.sqrt(1.0 + 2.0 * E2 * E2 * pp)
    r0 = (-(pp * E2 * p) / (1.0 + q)
          + math.sqrt(0.5 * A * A * (1.0 + 1.0 / q) - pp * (1.0 - E2) * z * z / (q * (1.0 + q))
                      - 0.5 * pp * p * p))
    u = math.hypot(p - E2 * r0, z)
    v = math.sqrt((p - E2 * r0) ** 2 + (1.0 - E2) * z * z)
    z0 = B * B * z / (A * v)
    return (math.degrees(math.atan((z + EP2 * z0) / p)), math.degrees(math.atan2(y, x)),
            u * (1.0 - B * B / (A * v)))


def enu_to_lla(enu: list[float]) -> tuple[float, float, float]:
    """The world point ``enu`` [m; ENU at ORIGIN] as latitude, longitude [deg], altitude [m]."""
    lat0, lon0, alt0 = ORIGIN
    phi, lam = math.radians(lat0), math.radians(lon0)
    east = np.array([-math.sin(lam), math.cos(lam), 0.0])
    north = np.array([-math.sin(phi) * math.cos(lam), -math.sin(phi) * math.sin(lam),
                      math.cos(phi)])
    up = np.array([math.cos(phi) * math.cos(lam), math.cos(phi) * math.sin(lam), math.sin(phi)])
    return geodetic(ecef(lat0, lon0, alt0) + enu[0] * east + enu[1] * north + enu[2] * up)


@dataclass(frozen=True)
class GeoEntry:
    """A line of geo.txt as ODM keeps it."""

    x: float
    y: float
    z: float | None
    yaw: float | None
    pitch: float | None
    roll: float | None


def read_geo_as_odm(text: str) -> tuple[str, dict[str, GeoEntry]]:
    """geo.txt parsed as OpenDroneMap's ``opendm/geo.py`` ``GeoFile`` does: BOM stripped,
    first line the SRS, then every line not empty and not starting with '#' split on
    whitespace: name, x, y, optional z, and yaw, pitch, roll only when all three are there
    (NaN in any: none); a line of fewer than three fields is malformed (a warning in ODM,
    a failure here)."""
    lines = [s.strip() for s in text.strip().replace("\ufeff", "").split("\n")]
    srs, entries = lines[0], {}
    for line in lines[1:]:
        if line == "" or line[0] == "#":
            continue
        parts = line.split()
        assert len(parts) >= 3, f"malformed geo line: {line}"
        x, y = float(parts[1]), float(parts[2])
        z = float(parts[3]) if len(parts) >= 4 else None
        yaw = pitch = roll = None
        if len(parts) >= 7:
            yaw, pitch, roll = (float(p) for p in parts[4:7])
            if math.isnan(yaw) or math.isnan(pitch) or math.isnan(roll):
                yaw = pitch = roll = None
        entries[parts[0]] = GeoEntry(x, y, z, yaw, pitch, roll)
    return srs, entries


def odm_axes(yaw: float, pitch: float, roll: float) -> tuple[np.ndarray, np.ndarray]:
    """(optical axis, image x axis) [world ENU] of a camera at ODM's yaw, pitch, roll
    [deg], by ``compute_opk``'s rotations: cnb (yaw-pitch-roll, NED) times cbb (image x →
    body y, image y → body x, image z → body −z); the camera looks along −z of the image."""
    y, p, r = math.radians(yaw), math.radians(pitch), math.radians(roll)
    cy, sy, cp, sp, cr, sr = (math.cos(y), math.sin(y), math.cos(p), math.sin(p), math.cos(r),
                              math.sin(r))
    cnb = np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                    [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                    [-sp, cp * sr, cp * cr]])
    cbb = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    rot = cnb @ cbb

    def enu(ned: np.ndarray) -> np.ndarray:
        return np.array([ned[1], ned[0], -ned[2]])

    return enu(rot @ np.array([0.0, 0.0, -1.0])), enu(rot @ np.array([1.0, 0.0, 0.0]))


def expected_names(doc: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Image name → capture row: each drone's rows in time order, ``<agent>_0001.jpg`` on."""
    out: dict[str, dict[str, Any]] = {}
    for agent in {str(r["agent"]) for r in doc["captures"]}:
        rows = sorted((r for r in doc["captures"] if r["agent"] == agent), key=lambda r: r["t"])
        out.update({f"{agent}_{k:04d}.jpg": r for k, r in enumerate(rows, start=1)})
    return out


def heading_pitch(direction: list[float], right: list[float]) -> tuple[float, float]:
    """Compass heading [deg, clockwise from north] and elevation [deg, + up] of a logged
    optical axis (the heading from the image's right axis when the axis is vertical)."""
    e, n, u = direction
    if math.hypot(e, n) < 1e-6:  # straight up or down: the top of the image faces r rotated
        e, n = -right[1], right[0]
    return math.degrees(math.atan2(e, n)) % 360.0, math.degrees(math.asin(u))


def angle_diff(a: float, b: float) -> float:
    """|a − b| on the circle [deg]."""
    return abs((a - b + 180.0) % 360.0 - 180.0)


def read_csv(path: Path) -> list[dict[str, str]]:
    with path.open(encoding="utf-8", newline="") as fh:
        return list(csv.DictReader(fh))


# -- tests -------------------------------------------------------------------------------------


def test_the_tests_geodesy_inverts_its_forward_formula() -> None:
    for lat, lon, h in ((47.3977, 8.5456, 488.0), (-33.9, 151.2, -20.0), (78.0, -100.0, 3e3)):
        got = geodetic(ecef(lat, lon, h))
        assert abs(got[0] - lat) < 1e-10 and abs(got[1] - lon) < 1e-10
        assert abs(got[2] - h) < 1e-6


def test_geo_txt_as_odm_reads_it(export: Export) -> None:
    """Every image is in geo.txt, at the logged camera position (independent WGS-84), with
    angles that give back, through ODM's own rotation, the logged optical and image x axes."""
    srs, entries = read_geo_as_odm((export.geo_dir / "geo.txt").read_text(encoding="utf-8"))
    assert srs == "EPSG:4326"
    rows = expected_names(export.doc)
    assert set(entries) == set(rows)
    assert len(entries) == len(export.doc["captures"])
    for name, row in rows.items():
        e = entries[name]
        lat, lon, alt = enu_to_lla(row["position"])
        assert abs(e.x - lon) < 1e-7 and abs(e.y - lat) < 1e-7, name  # x longitude, y latitude
        assert e.z is not None and abs(e.z - alt) < 1e-3, name
        assert e.yaw is not None and e.pitch is not None and e.roll is not None, name
        look, right = odm_axes(e.yaw, e.pitch, e.roll)
        assert np.allclose(look, row["direction"], atol=1e-6), (name, look, row["direction"])
        assert np.allclose(right, row["right"], atol=1e-6), (name, right, row["right"])
        heading, elevation = heading_pitch(row["direction"], row["right"])
        assert angle_diff(e.yaw, heading) < 1e-5 and e.roll == 0.0
        assert abs(e.pitch - (90.0 + elevation)) < 1e-5  # ODM: 0 nadir, 90 level


def test_images_csv_rows_are_the_logged_poses(export: Export) -> None:
    rows = expected_names(export.doc)
    table = read_csv(export.geo_dir / "images.csv")
    assert [r["image"] for r in table] == [r["image"] for r in sorted(
        table, key=lambda r: float(r["t_s"]))]  # in time order
    assert sorted(r["image"] for r in table) == sorted(rows)
    _, entries = read_geo_as_odm((export.geo_dir / "geo.txt").read_text(encoding="utf-8"))
    for r in table:
        row = rows[r["image"]]
        assert r["agent"] == row["agent"] and abs(float(r["t_s"]) - row["t"]) < 1e-6
        assert np.allclose([float(r[k]) for k in ("x_m", "y_m", "z_m")], row["position"],
                           atol=1e-6)
        heading, elevation = heading_pitch(row["direction"], row["right"])
        assert angle_diff(float(r["yaw_deg"]), heading) < 1e-5, r["image"]
        assert abs(float(r["pitch_deg"]) - elevation) < 1e-5, r["image"]
        assert float(r["roll_deg"]) == 0.0
        lat, lon, alt = enu_to_lla(row["position"])
        assert abs(float(r["lat_deg"]) - lat) < 1e-7 and abs(float(r["lon_deg"]) - lon) < 1e-7
        assert abs(float(r["alt_m"]) - alt) < 1e-3
        assert [int(i) for i in r["landmarks"].split(";")] == row["landmarks"]
        assert r["gsd_worst_mm"] == "" and r["gsd_median_mm"] == ""  # no camera model
        assert abs(float(r["lon_deg"]) - entries[r["image"]].x) < 1e-9
    assert "GSD columns left empty" in export.geo_stdout


def test_geojson_has_one_point_per_image(export: Export) -> None:
    doc = json.loads((export.geo_dir / "captures.geojson").read_text(encoding="utf-8"))
    assert doc["type"] == "FeatureCollection"
    rows = expected_names(export.doc)
    assert len(doc["features"]) == len(rows)
    _, entries = read_geo_as_odm((export.geo_dir / "geo.txt").read_text(encoding="utf-8"))
    seen = set()
    for f in doc["features"]:
        assert f["type"] == "Feature" and f["geometry"]["type"] == "Point"
        props = f["properties"]
        name = props["image"]
        seen.add(name)
        lon, lat, alt = f["geometry"]["coordinates"]
        e = entries[name]
        assert abs(lon - e.x) < 1e-9 and abs(lat - e.y) < 1e-9
        assert e.z is not None and abs(alt - e.z) < 1e-3
        row = rows[name]
        heading, elevation = heading_pitch(row["direction"], row["right"])
        assert props["agent"] == row["agent"] and props["t"] == row["t"]
        assert angle_diff(props["yaw"], heading) < 1e-6
        assert abs(props["pitch"] - elevation) < 1e-6 and props["roll"] == 0.0
        assert props["landmarks"] == row["landmarks"]
        assert "gsd_mm" not in props  # no camera model
    assert seen == set(rows)


def gsd_by_hand(row: dict[str, Any], doc: dict[str, Any], pixel_angle: float
                ) -> tuple[float, float]:
    """Worst and median r·pixel_angle/cos(incidence) [mm/px] over the row's landmarks."""
    marks = {int(m["id"]): m for m in doc["landmarks"]}
    p = row["position"]
    gsd = []
    for lid in row["landmarks"]:
        q, n = marks[lid]["position"], marks[lid]["normal"]
        d = [p[i] - q[i] for i in range(3)]
        r = math.sqrt(sum(v * v for v in d))
        cos_inc = sum(d[i] * n[i] for i in range(3)) / (r * math.sqrt(sum(v * v for v in n)))
        gsd.append(1000.0 * r * pixel_angle / cos_inc)
    return max(gsd), statistics.median(gsd)


def test_gsd_columns_from_a_camera(export: Export) -> None:
    camera = Camera.from_sensor((13.2, 8.8), 8.8, (5472, 3648))
    pixel_angle = max(13.2 / 5472, 8.8 / 3648) / 8.8
    text = images_csv(image_records(export.doc, camera=camera))
    table = list(csv.DictReader(text.splitlines()))
    rows = expected_names(export.doc)
    assert len(table) == len(rows)
    spread = 0
    for r in table:
        worst, median = gsd_by_hand(rows[r["image"]], export.doc, pixel_angle)
        assert abs(float(r["gsd_worst_mm"]) - worst) < 1e-4, r["image"]
        assert abs(float(r["gsd_median_mm"]) - median) < 1e-4, r["image"]
        spread += worst > median + 1e-3
        assert r["lat_deg"] == ""  # no origin given
    assert spread > 0  # some image sees landmarks at different GSDs: worst is not the median


def test_gsd_needs_the_landmarks_the_captures_name(export: Export) -> None:
    doc = dict(export.doc, landmarks=[m for m in export.doc["landmarks"] if m["id"] != 2])
    camera = Camera(pixel_angle=3e-4, image_px=(4000, 3000))
    with pytest.raises(ValueError, match=r"\[2\]"):
        image_records(doc, camera=camera)
    assert image_records(doc)[0].gsd_worst_mm is None  # without a camera they are not needed


def camera_scenario(folder: Path) -> Path:
    """The gabled house's scenario with a ``[camera]`` table (a 1-inch 20 MP camera behind an
    8.8 mm lens) instead of its field of view, written into ``folder``."""
    text = scenario_path("inspect_gabled_house").read_text(encoding="utf-8")
    mesh = scenario_path("inspect_gabled_house").parent / "meshes" / "gabled_house.stl"
    text = text.replace('mesh = "meshes/gabled_house.stl"', f'mesh = "{mesh.as_posix()}"')
    text = text.replace("fov_deg = [90.0, 70.0]\n", "\n[camera]\nsensor_mm = [13.2, 8.8]\n"
                        "focal_mm = 8.8\nimage_px = [5472, 3648]\n")
    sc = folder / "inspect_gabled_house.toml"
    sc.write_text(text, encoding="utf-8")
    return sc


def check_gsd_csv(path: Path, doc: dict[str, Any]) -> None:
    """Every row of images.csv has the worst GSD of the 1-inch camera of
    :func:`camera_scenario`."""
    table = read_csv(path)
    rows = expected_names(doc)
    assert len(table) == len(rows)
    pixel_angle = max(13.2 / 5472, 8.8 / 3648) / 8.8
    for r in table:
        worst, _ = gsd_by_hand(rows[r["image"]], doc, pixel_angle)
        assert abs(float(r["gsd_worst_mm"]) - worst) < 1e-4


def test_cli_reads_the_camera_of_the_scenario(export: Export, tmp_path: Path) -> None:
    """``--scenario`` with a ``[camera]`` table fills the GSD columns from it."""
    sc = camera_scenario(tmp_path)
    run = export.geo_dir.parent / "run"
    res = viscover("export-images", str(run), "--out", str(tmp_path / "out"), "--scenario",
                   str(sc))
    assert res.returncode == 0, res.stderr
    check_gsd_csv(tmp_path / "out" / "images.csv", export.doc)
    assert "GSD columns left empty" not in res.stdout


def test_a_launched_runs_scenario_gives_the_camera(export: Export, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """A run folder (launch.json naming its scenario, report/result.json) needs no
    ``--scenario``: the camera is the named scenario's, as ``viscover report`` finds it."""
    sc = camera_scenario(tmp_path)
    run = tmp_path / "run"
    (run / "report").mkdir(parents=True)
    (run / "launch.json").write_text(json.dumps({"scenario": str(sc)}), encoding="utf-8")
    (run / "report" / "result.json").write_text(json.dumps(export.doc), encoding="utf-8")
    assert main(["export-images", str(run), "--out", str(tmp_path / "out")]) == 0
    check_gsd_csv(tmp_path / "out" / "images.csv", export.doc)
    assert "GSD columns left empty" not in capsys.readouterr().out


def test_without_origin_only_images_csv(export: Export) -> None:
    assert sorted(p.name for p in export.plain_dir.iterdir()) == ["images.csv"]
    lines = [s for s in export.plain_stdout.splitlines() if "--origin" in s]
    assert len(lines) == 1 and "geo.txt" in lines[0] and "GeoJSON".lower() in lines[0].lower()
    table = read_csv(export.plain_dir / "images.csv")
    assert len(table) == len(export.doc["captures"])
    assert all(r["lat_deg"] == r["lon_deg"] == r["alt_m"] == "" for r in table)


def test_missing_run_dir_is_one_line_and_status_2(tmp_path: Path) -> None:
    res = viscover("export-images", str(tmp_path / "nowhere"), "--out", str(tmp_path / "o"),
                   "--origin", ORIGIN_ARG)
    assert res.returncode == 2
    assert len(res.stderr.strip().splitlines()) == 1 and "nowhere" in res.stderr
    assert "Traceback" not in res.stderr
    assert not (tmp_path / "o").exists()
