"""What an inspection team takes home: one record per image of an inspection run, and the files
photogrammetry reads (``viscover export-images``; pure but for :func:`write_image_files`).

Each row of ``result.json``'s ``captures`` is one image (:mod:`agent.sim.inspection_report`):
the time ``t`` [s], the drone, the landmarks imaged, the camera ``position`` [m; world ENU], its
unit optical axis ``direction`` and unit image x axis ``right`` (horizontal: the camera has no
roll) [world ENU]. The rows are read by :func:`agent.flight.refly.viewpoints`, the reader of
``viscover export-plan``, so both commands see the same images in the same order.

Conventions of every record and of ``images.csv`` and ``captures.geojson``:

* **image name** ``<agent>_<index:04d>.jpg``; ``index`` counts each drone's images from 1 in
  time order (``A_0001.jpg`` is drone A's first image).
* **x, y, z** [m; world ENU]: the camera position.
* **yaw** [degrees in [0, 360)]: the camera's compass heading, clockwise from north (0 north,
  90 east): the heading of ẑ × ``right``, which is the heading of the optical axis's horizontal
  part, and for a camera looking straight down the direction the top of its image faces.
  Empty (NaN) only for a vertical camera logged without ``right``.
* **pitch** [degrees in [−90, 90]]: the optical axis's elevation above the horizontal plane,
  asin(direction_z): 0 level, negative looking down, −90 straight down.
* **roll** [degrees]: 0: the image x axis is horizontal.
* **lat, lon** [degrees, WGS-84] and **alt** [m] (with an origin): the camera position through
  :func:`agent.flight.geodetic.enu_to_geodetic`; ``alt`` is in the datum of the origin's
  altitude (AMSL if that was given AMSL).
* **GSD** [mm/px] (with a camera model, :mod:`agent.core.camera`): the ground sampling
  distance r·(s/f)/cos β of each landmark in view (range r, incidence β between the landmark's
  normal and the line to the camera), the worst (largest) and the median over the image's
  landmarks.

``geo.txt`` is OpenDroneMap's image geolocation file. ODM's documentation (OpenDroneMap/docs,
``source/geo.rst``): first line the projection (``EPSG:4326``, a PROJ string or ``WGS84 UTM
<zone>[N|S]``), then ``image_name geo_x geo_y [geo_z] [yaw] [pitch] [roll] [horz accuracy]
[vert accuracy] [extras...]``, degrees and metres; it is picked up when named ``geo.txt`` in
the project folder. ODM's reader (OpenDroneMap/ODM ``opendm/geo.py``, ``GeoFile``): strips a BOM,
takes line 1 as the SRS (``opendm/location.py`` ``parse_srs_header``), skips empty lines and
lines starting with ``#``, splits every other line on whitespace (so an image name cannot hold
a space), needs at least name, x, y; z is the 4th field; yaw, pitch, roll are read only when
all three are there (fields 5-7), NaN in any of them means none; then
``ODM_Photo.update_with_geo_entry`` sets latitude = y, longitude = x (for EPSG:4326 x is the
longitude), altitude = z, and ``stages/dataset.py`` matches entries to photos by file name and
calls ``compute_opk``. ODM's angles follow its "normalised YPR conventions (assuming nadir
camera)" (``opendm/photo.py``): yaw 0: top of image points north, 90: east; **pitch 0: nadir
camera, 90: looking forward** (horizontal); roll 0 for a gimbal; DJI's gimbal pitch (−90 nadir)
is turned into it as 90 + pitch. ``compute_opk`` builds the attitude yaw-pitch-roll in NED with
the image's top along the body's x axis and the camera looking down its z axis, so with
ODM pitch p the optical axis is (cos yaw·sin p, sin yaw·sin p, cos p) [NED]. Hence geo.txt's
columns here: lon, lat, alt, yaw (as above), **pitch + 90** (this module's pitch turned into
ODM's: 0 nadir, 90 level, 180 straight up), roll 0.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agent.core.camera import Camera, ground_sampling_distance
from agent.flight.geodetic import Origin, enu_to_geodetic
from agent.flight.refly import Structure, viewpoints

Array = NDArray[np.float64]

IMAGES_CSV = "images.csv"
GEO_TXT = "geo.txt"
GEOJSON = "captures.geojson"
#: What export-images says about a run without captures (a coverage mission's).
NO_IMAGES = "no captures: export-images needs an inspection mission's run"
#: The projection line of geo.txt: WGS-84 longitude, latitude (ODM reads x as longitude).
GEO_PROJECTION = "EPSG:4326"
#: images.csv's header, in column order.
CSV_COLUMNS = ("image", "t_s", "agent", "x_m", "y_m", "z_m", "yaw_deg", "pitch_deg",
               "roll_deg", "lat_deg", "lon_deg", "alt_m", "gsd_worst_mm", "gsd_median_mm",
               "landmarks")
#: An agent id that can start an image file name: ODM splits geo.txt on whitespace.
_SAFE_ID = re.compile(r"^[A-Za-z0-9_-][A-Za-z0-9_.-]*$")


@dataclass(frozen=True)
class ImageRecord:
    """One image: file ``name``, time ``t`` [s], drone ``agent``, camera ``position`` (3,)
    [m; world ENU], ``yaw`` (compass heading [deg, clockwise from north]), ``pitch`` (elevation
    of the optical axis [deg, negative down]) and ``roll`` [deg] of the camera, the
    ``landmarks`` in view (ids); with an origin ``lat``, ``lon`` [deg] and ``alt`` [m]; with a
    camera model the worst and median ground sampling distance over the landmarks in view
    ``gsd_worst_mm``, ``gsd_median_mm`` [mm/px]."""

    name: str
    t: float
    agent: str
    position: Array
    yaw: float
    pitch: float
    roll: float
    landmarks: tuple[int, ...]
    lat: float | None = None
    lon: float | None = None
    alt: float | None = None
    gsd_worst_mm: float | None = None
    gsd_median_mm: float | None = None

    @property
    def geodetic(self) -> bool:
        """Whether the record has latitude, longitude and altitude."""
        return self.lat is not None and self.lon is not None and self.alt is not None

    @property
    def odm_pitch(self) -> float:
        """The pitch in OpenDroneMap's convention [deg]: 0 nadir, 90 level (pitch + 90)."""
        return self.pitch + 90.0


def image_name(agent: str, index: int) -> str:
    """``<agent>_<index:04d>.jpg``: the file name of a drone's ``index``-th image (from 1)."""
    return f"{agent}_{index:04d}.jpg"


def landmark_rows(sorted_ids: NDArray[np.int64], order: NDArray[np.int64],
                  wanted: Sequence[int]) -> NDArray[np.int64]:
    """Rows of the run's landmark arrays holding each id of ``wanted``, given the ids sorted
    (``sorted_ids``) and the sorting permutation ``order``; ValueError for an id that is not a
    landmark of the run."""
    w = np.asarray(wanted, dtype=np.int64)
    if sorted_ids.size == 0:
        raise ValueError("the run has no landmarks")
    at = np.minimum(np.searchsorted(sorted_ids, w), sorted_ids.size - 1)
    found = sorted_ids[at] == w
    if not np.all(found):
        raise ValueError(f"landmark id(s) {w[~found][:5].tolist()} imaged but not among the "
                         "run's landmarks")
    return np.asarray(order[at], dtype=np.int64)


def image_gsd(position: Array, q: Array, u: Array, camera: Camera) -> tuple[float, float]:
    """Worst (largest) and median ground sampling distance [mm/px] over landmarks at ``q`` with
    unit normals ``u`` (m, 3) [m; world ENU], m >= 1, seen from camera ``position`` (3,)
    [m; world ENU] (+inf for one facing away)."""
    g = ground_sampling_distance(position[None, :], q, u, camera.pixel_angle)[0] * 1000.0
    return float(g.max()), float(np.median(g))


def image_records(doc: Mapping[str, Any], camera: Camera | None = None,
                  origin: Origin | None = None) -> list[ImageRecord]:
    """One record per image (capture row) of ``result.json`` ``doc``, in time order (ties: the
    drones' order in ``agents``); geodetic fields with ``origin``, GSD with ``camera`` (which
    needs the run's ``landmarks``). ValueError for a run without captures, malformed rows, an
    agent id that cannot name a file, or (with a camera) unknown landmarks."""
    rows = doc.get("captures")
    if not isinstance(rows, list) or not rows:
        raise ValueError(NO_IMAGES)
    views = viewpoints(doc)
    landmarks = Structure.from_doc(doc) if camera is not None else None
    if camera is not None and landmarks is None:
        raise ValueError("no landmarks in the run: the ground sampling distance needs them")
    for agent in views:
        if not _SAFE_ID.match(agent):
            raise ValueError(f"agent id {agent!r} cannot start an image file name (letters, "
                             "digits, '_', '-', '.'; no spaces, not starting with '.')")
    ids = np.asarray(landmarks.ids if landmarks is not None else [], dtype=np.int64)
    order = np.argsort(ids, kind="stable").astype(np.int64)
    sorted_ids = ids[order]
    rank = {a: k for k, a in enumerate(views)}
    out: list[ImageRecord] = []
    for agent, vps in views.items():
        for k, vp in enumerate(vps, start=1):
            worst = median = None
            if camera is not None and landmarks is not None and vp.landmarks:
                rows = landmark_rows(sorted_ids, order, vp.landmarks)
                worst, median = image_gsd(vp.position, landmarks.q[rows], landmarks.u[rows],
                                          camera)
            out.append(ImageRecord(name=image_name(agent, k), t=vp.t, agent=agent,
                                   position=vp.position, yaw=vp.heading, pitch=vp.pitch,
                                   roll=0.0, landmarks=vp.landmarks, gsd_worst_mm=worst,
                                   gsd_median_mm=median))
    out.sort(key=lambda r: (r.t, rank[r.agent], r.name))
    if origin is None:
        return out
    lat, lon, alt = enu_to_geodetic(np.array([r.position for r in out]), origin)
    return [replace(r, lat=float(lat[k]), lon=float(lon[k]), alt=float(alt[k]))
            for k, r in enumerate(out)]


def _num(x: float | None, digits: int) -> str:
    """``x`` with ``digits`` decimals; empty for None or NaN (CSV)."""
    if x is None or math.isnan(x):
        return ""
    return f"{x:.{digits}f}" if math.isfinite(x) else ("inf" if x > 0 else "-inf")


def images_csv(records: Sequence[ImageRecord]) -> str:
    """``images.csv``: a header (:data:`CSV_COLUMNS`) and one row per image: name, t [s],
    agent, x, y, z [m; world ENU], yaw, pitch, roll [deg], lat, lon [deg], alt [m] (empty
    without an origin), worst and median GSD [mm/px] (empty without a camera model), the
    landmark ids in view joined with ';'."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for r in records:
        x, y, z = (float(v) for v in r.position)
        w.writerow([r.name, _num(r.t, 6), r.agent, _num(x, 6), _num(y, 6), _num(z, 6),
                    _num(r.yaw, 6), _num(r.pitch, 6), _num(r.roll, 6), _num(r.lat, 10),
                    _num(r.lon, 10), _num(r.alt, 4), _num(r.gsd_worst_mm, 4),
                    _num(r.gsd_median_mm, 4), ";".join(str(i) for i in r.landmarks)])
    return buf.getvalue()


def geo_txt(records: Sequence[ImageRecord]) -> str:
    """OpenDroneMap's ``geo.txt``: ``EPSG:4326``, then per image ``name lon lat alt yaw pitch
    roll`` (degrees, metres; pitch in ODM's convention, 0 nadir and 90 level: see the module
    docstring; ``nan nan nan`` for a camera without a defined yaw, which ODM reads as no
    angles). ValueError if a record has no geodetic position."""
    lines = [GEO_PROJECTION]
    for r in records:
        if r.lat is None or r.lon is None or r.alt is None:
            raise ValueError(f"{r.name}: no geodetic position (give an origin)")
        angles = ("nan nan nan" if math.isnan(r.yaw) else
                  f"{r.yaw:.6f} {r.odm_pitch:.6f} {r.roll:.6f}")
        lines.append(f"{r.name} {r.lon:.10f} {r.lat:.10f} {r.alt:.4f} {angles}")
    return "\n".join(lines) + "\n"


def _finite(x: float | None) -> float | None:
    """``x`` if a finite number, else None (JSON has no NaN or infinity)."""
    return x if x is not None and math.isfinite(x) else None


def captures_geojson(records: Sequence[ImageRecord]) -> dict[str, Any]:
    """A GeoJSON FeatureCollection (RFC 7946) of one Point (lon, lat [deg], alt [m]) per image,
    with properties image, t [s], agent, yaw, pitch, roll [deg] (this module's conventions:
    pitch from the horizontal, negative down), gsd_mm and gsd_median_mm [mm/px] when known,
    landmarks (ids). ValueError if a record has no geodetic position."""
    features: list[dict[str, Any]] = []
    for r in records:
        if r.lat is None or r.lon is None or r.alt is None:
            raise ValueError(f"{r.name}: no geodetic position (give an origin)")
        props: dict[str, Any] = {"image": r.name, "t": r.t, "agent": r.agent,
                                 "yaw": _finite(r.yaw), "pitch": r.pitch, "roll": r.roll}
        if r.gsd_worst_mm is not None:
            props["gsd_mm"] = _finite(r.gsd_worst_mm)
            props["gsd_median_mm"] = _finite(r.gsd_median_mm)
        props["landmarks"] = list(r.landmarks)
        features.append({"type": "Feature",
                         "geometry": {"type": "Point", "coordinates": [r.lon, r.lat, r.alt]},
                         "properties": props})
    return {"type": "FeatureCollection", "features": features}


def write_image_files(records: Sequence[ImageRecord], out_dir: Path) -> list[Path]:
    """Write ``images.csv`` into ``out_dir`` (an existing folder), and ``geo.txt`` and
    ``captures.geojson`` when every record has a geodetic position; returns the paths
    written."""
    paths = [out_dir / IMAGES_CSV]
    paths[0].write_text(images_csv(records), encoding="utf-8")
    if records and all(r.geodetic for r in records):
        geo = out_dir / GEO_TXT
        geo.write_text(geo_txt(records), encoding="utf-8")
        gj = out_dir / GEOJSON
        gj.write_text(json.dumps(captures_geojson(records), indent=1, allow_nan=False) + "\n",
                      encoding="utf-8")
        paths += [geo, gj]
    return paths
