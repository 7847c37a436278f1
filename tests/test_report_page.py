"""``report.html`` as an inspection team reads it, read back with ``html.parser``.

``viscover simulate`` and ``viscover report`` write the same page: the date, scenario digest
and software version; a summary; the time axis explained; the structure figure and one row
per landmark (worst first) whose numbers are recomputed here, independently, from what
``result.json`` logged (the captures' camera positions, or the final poses) with eq. 3.1
written out; the events led by the phases (take-off, trades, captures, landing), failsafes
summarised, every time on the result's mission time axis.

The page is also rendered by a headless Chromium (Debian's ``chromium-headless-shell``) when
one is installed; the test says so and skips otherwise (the structural checks always run).
"""

from __future__ import annotations

import base64
import datetime
import io
import json
import shutil
import subprocess
import time
from html.parser import HTMLParser
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from agent.cli import main
from agent.config.digest import scenario_digest
from agent.config.parse import load_scenario
from agent.mission.recorder import Recorder, line_event
from agent.net.memory import MemoryNetwork
from agent.storage import recording as fmt
from agent.wire import keys
from agent.wire.peer import Pose
from agent.world.structure import resolve_structure
from tests.conftest import scenario_path
from tests.test_status_identity import PUB, state

PHASES = ["Take-off", "Trades", "Captures", "Landing", "Failsafes", "Other events"]


class Page(HTMLParser):
    """Headings, tables (rows of cell texts, by id or position), images, paragraphs."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.headings: list[tuple[str, str]] = []
        self.tables: list[tuple[str, list[list[str]]]] = []
        self.images: list[tuple[str, str]] = []  # (section heading, src)
        self.paragraphs: list[str] = []
        self._text: list[str] | None = None
        self._tag = ""
        self.text = text
        self.feed(text)

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        if tag == "table":
            self.tables.append((a.get("id") or "", []))
        elif tag == "tr":
            self.tables[-1][1].append([])
        elif tag in ("td", "th", "h1", "h2", "h3", "p"):
            self._text, self._tag = [], tag
        elif tag == "img":
            self.images.append((self.headings[-1][1], a.get("src") or ""))

    def handle_data(self, data: str) -> None:
        if self._text is not None:
            self._text.append(data)

    def handle_endtag(self, tag: str) -> None:
        if self._text is None or tag != self._tag:
            return
        text, self._text = "".join(self._text).strip(), None
        if tag in ("td", "th"):
            self.tables[-1][1][-1].append(text)
        elif tag == "p":
            self.paragraphs.append(text)
        else:
            self.headings.append((tag, text))

    def table(self, name: str) -> list[list[str]]:
        """The table with id ``name`` (header row first)."""
        return next(rows for tid, rows in self.tables if tid == name)

    def table_after(self, heading: str) -> list[list[str]]:
        """The first table after the h3 ``heading`` (headings and tables in page order)."""
        text = self.text
        start = text.index(f"<h3>{heading}</h3>")
        end = text.find("<h3>", start + 1)
        chunk = text[start:end if end >= 0 else len(text)]
        return Page(chunk).tables[0][1] if "<table" in chunk else []

    def meta(self) -> dict[str, str]:
        return {r[0]: r[1] for r in self.table("meta")}


def eq31(p: np.ndarray, v: np.ndarray, q: np.ndarray, u: np.ndarray, d_opt: float
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 3.1 written out for one camera (p, v) and landmarks (q, u): quality
    f(r)·cos α·cos β with f(r) = (r/d_opt)·exp(1 − r/d_opt), and r, β [deg]."""
    d = q - p
    r = np.linalg.norm(d, axis=1)
    cos_a = d @ v / r
    cos_b = -(d * u).sum(axis=1) / r
    f = r / d_opt * np.exp(1.0 - r / d_opt)
    qual = np.where((cos_a > 0) & (cos_b > 0), f * cos_a * cos_b, 0.0)
    return qual, r, np.degrees(np.arccos(np.clip(cos_b, -1.0, 1.0)))


def _landmark_rows(page: Page) -> dict[int, dict[str, str]]:
    head, *rows = page.table("landmarks")
    return {int(r[0]): dict(zip(head, r, strict=True)) for r in rows}


def _check_common(page: Page, scenario: str, digest: str) -> None:
    """What every report page says, in this order."""
    assert page.headings[0] == ("h1", f"viscover report: {scenario}")
    h2 = [t for h, t in page.headings if h == "h2"]
    # An inspection's page has its resolution section after the landmarks.
    want = ["Summary", "Time axis", "Landmarks"] + (["Resolution"] if "Resolution" in h2
                                                   else []) + ["Events"]
    assert h2[:len(want)] == want, h2
    assert [t for h, t in page.headings if h == "h3"] == PHASES
    meta = page.meta()
    assert meta["scenario digest"] == digest
    assert meta["software"].startswith(f"viscover {metadata.version('viscover')}")
    assert any(p.startswith("τ is ") and "mission time" in p for p in page.paragraphs)


@pytest.fixture(scope="module")
def tower(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, float, float]:
    """``viscover simulate`` of the tower, once for the module's tests (they only read it):
    its output folder and the wall times [s since the epoch] before and after it ran."""
    out = tmp_path_factory.mktemp("report_page") / "tower"
    t0 = time.time()
    assert main(["simulate", str(scenario_path("tower")), "--out", str(out), "--quiet"]) == 0
    return out, t0, time.time()


def test_simulate_writes_the_inspection_page(tower: tuple[Path, float, float]) -> None:
    out, t0, t1 = tower
    page = Page((out / "report.html").read_text(encoding="utf-8"))
    doc = json.loads((out / "result.json").read_text())
    sc = resolve_structure(load_scenario(str(scenario_path("tower"))))
    _check_common(page, "tower", scenario_digest(sc))
    date = datetime.datetime.strptime(page.meta()["date (UTC)"].split(" UTC")[0],
                                      "%Y-%m-%d %H:%M:%S").replace(tzinfo=datetime.UTC)
    assert t0 - 2 <= date.timestamp() <= t1 + 1
    summary = dict(page.table("summary"))
    assert summary["landmarks"].startswith("31/31 captured")
    assert summary["inspection"].startswith("captured 31/31 at quality >= 0.3")
    # the structure first, the resolution histogram, then the other figures (captures.png
    # is folded into the structure's)
    assert [s for s, _src in page.images] == ["Landmarks", "Resolution"] + ["Figures"] * 3
    # the resolution table: its groups hold every landmark, each captured one counted once
    res = page.table("resolution")[1:]
    assert sum(int(r[1]) for r in res) == len(doc["landmark_ids"])
    assert sum(int(r[2]) for r in res) == len(doc["inspection"]["captured"])
    img = Image.open(io.BytesIO(base64.b64decode(page.images[0][1].split(",", 1)[1])))
    pixels = np.asarray(img.convert("RGB")).reshape(-1, 3)
    assert img.size[0] > 500 and len(np.unique(pixels, axis=0)) > 50
    # every landmark's row, recomputed from the logged captures
    q = np.array([lm["position"] for lm in doc["landmarks"]])
    u = np.array([lm["normal"] for lm in doc["landmarks"]])
    rows = _landmark_rows(page)
    assert sorted(rows) == doc["landmark_ids"]
    best: dict[int, tuple[float, dict[str, Any]]] = {}
    for c in doc["captures"]:
        for lid, qual in zip(c["landmarks"], c["quality"], strict=True):
            if lid not in best or qual > best[lid][0]:
                best[lid] = (qual, c)
    for j, lid in enumerate(doc["landmark_ids"]):
        qual, c = best[lid]
        p, v = np.array(c["position"]), np.array(c["direction"])
        mine, r, beta = eq31(p, v, q[j:j + 1], u[j:j + 1], doc["d_opt"])
        row = rows[lid]
        assert row["status"] == "captured" and row["by"] == c["agent"]
        assert float(row["quality"]) == pytest.approx(qual, abs=6e-4)
        assert float(row["quality"]) >= 0.3 - 6e-4
        assert float(row["quality"]) <= mine[0] + 1e-3  # eq. 3.1, before the capture's limits
        assert float(row["distance [m]"]) == pytest.approx(r[0], abs=6e-3)
        assert float(row["incidence [°]"]) == pytest.approx(beta[0], abs=0.06)
        assert float(row["τ [s]"]) == pytest.approx(c["t"], abs=0.06)
    quals = [float(r[2]) for r in page.table("landmarks")[1:]]
    assert quals == sorted(quals)  # worst first
    caps = page.table_after("Captures")
    assert len(caps) - 1 == len(doc["captures"])
    assert "no take-off" in page.text and "no landing" in page.text
    lines = (out / "landmarks.csv").read_text().splitlines()
    assert lines[0].startswith("id,status,") and len(lines) == 32


def test_simulate_coverage_page_from_the_final_poses(tmp_path: Path) -> None:
    out = tmp_path / "cube"
    assert main(["simulate", str(scenario_path("cube_6_2")), "--out", str(out), "--quiet"]) == 0
    page = Page((out / "report.html").read_text(encoding="utf-8"))
    doc = json.loads((out / "result.json").read_text())
    _check_common(page, "cube_6_2", scenario_digest(load_scenario(
        str(scenario_path("cube_6_2")))))
    q = np.array([lm["position"] for lm in doc["landmarks"]])
    u = np.array([lm["normal"] for lm in doc["landmarks"]])
    fin = doc["final_poses"]
    per = [eq31(np.array(fin[a]["position"]), np.array(fin[a]["direction"]), q, u,
                doc["d_opt"]) for a in doc["agents"]]
    qual = np.array([x[0] for x in per])
    k = np.argmax(qual, axis=0)
    rows = _landmark_rows(page)
    for j, lid in enumerate(doc["landmark_ids"]):
        row = rows[lid]
        if qual[k[j], j] > 0:
            assert row["status"] == "seen" and row["by"] == doc["agents"][k[j]]
            assert float(row["quality"]) == pytest.approx(qual[k[j], j], abs=6e-4)
            assert float(row["distance [m]"]) == pytest.approx(per[k[j]][1][j], abs=6e-3)
            assert float(row["incidence [°]"]) == pytest.approx(per[k[j]][2][j], abs=0.06)
        else:
            assert row["status"] == "unseen" and row["quality"] == "0.000"
    assert page.images[0][0] == "Landmarks"


def _recorded_run(out: Path) -> None:
    """hexagon_5_3 recorded: three drones' states and poses, A's flight lines (take-off,
    a failsafe twice, landing), one trade of landmark 6 from A to B."""
    sc = load_scenario(str(scenario_path("hexagon_5_3")))
    net = MemoryNetwork()
    rec = Recorder(net.transport("rec"), sc, "m", out, pose_hz=1e6, scene_hz=1e6)
    tp = net.transport("agents")

    def flight(text: str) -> None:
        """A's flight line ``text``, recorded as its event."""
        ev = line_event("A", f"viscover-flight-agent A: {text}")
        assert ev is not None
        rec.event(ev)

    for text in ("armed", "took off", "on station at (0, 0, 1) m"):
        flight(text)
    owned = {"A": {3: 0, 6: 0}, "B": {2: 0, 4: 0}, "C": {1: 0, 5: 0}}
    for k in range(8):
        if k == 4:
            owned["A"], owned["B"] = {3: 0}, {2: 0, 4: 0, 6: 1}
            flight("mocap lost: level hover")
        for i, aid in enumerate("ABC"):
            tw = {"B": 1} if aid == "A" and k >= 4 else {"A": 1} if aid == "B" and k >= 4 \
                else {}
            tp.publish(keys.state_key("m", aid), PUB.encode(state(
                aid, k + 1, 0.2 * k, owned[aid], ok=len(tw), trades_with=tw,
                complete=k == 7)))
            tp.publish(keys.pose_key("m", aid), PUB.encode(Pose(
                sender=aid, seq=k, t=0.2 * k, p=(float(i) - 1.0, 0.1 * k, 0.0),
                v=(0.0, 1.0, 0.0))))
        time.sleep(0.01)
    flight("mocap lost: level hover")
    for text in ("landing", "landed"):
        flight(text)
    rec.close()


def test_report_of_a_recording_is_the_same_page(tmp_path: Path) -> None:
    _recorded_run(tmp_path)
    assert main(["report", str(tmp_path), "--no-plots"]) == 0
    out = tmp_path / "report"
    page = Page((out / "report.html").read_text(encoding="utf-8"))
    doc = json.loads((out / "result.json").read_text())
    events = [json.loads(x) for x in (tmp_path / fmt.EVENTS_NAME).read_text().splitlines()]
    _check_common(page, "hexagon_5_3", scenario_digest(load_scenario(
        str(scenario_path("hexagon_5_3")))))
    started = events[0]["time"]  # the recording's start, within the recorder's set-up
    date = datetime.datetime.strptime(page.meta()["date (UTC)"], "%Y-%m-%d %H:%M:%S UTC")
    assert abs(date.replace(tzinfo=datetime.UTC).timestamp() - started) < 2
    axis = doc["time_axis"]

    def tau(ev: dict[str, Any]) -> float:
        return float(axis["scale"]) * (float(ev["time"]) - float(axis["wall_origin"]))

    assert any("mission seconds per wall second" in p for p in page.paragraphs)
    take = page.table_after("Take-off")
    assert [r[2] for r in take[1:]] == ["armed", "took off", "on station at (0, 0, 1) m"]
    flights = [e for e in events if e["kind"] == "flight"]
    assert [float(r[0]) for r in take[1:]] == pytest.approx(
        [round(tau(e), 1) for e in flights[:3]], abs=0.051)
    assert [r[2] for r in page.table_after("Landing")[1:]] == ["landing", "landed"]
    (fail,) = page.table_after("Failsafes")[1:]
    lost = [e for e in events if e["kind"] == "failsafe"]
    assert fail[:3] == ["A", "mocap lost: level hover", "2"]
    assert [float(fail[3]), float(fail[4])] == pytest.approx(
        [tau(lost[0]), tau(lost[1])], abs=0.051)
    trades = page.table_after("Trades")[1:]
    assert len(trades) == 1 and trades[0][1] == "A ⇄ B"
    # the landmarks from the final poses, every one recomputed
    q = np.array([lm["position"] for lm in doc["landmarks"]])
    u = np.array([lm["normal"] for lm in doc["landmarks"]])
    fin = doc["final_poses"]
    per = [eq31(np.array(fin[a]["position"]), np.array(fin[a]["direction"]), q, u,
                doc["d_opt"]) for a in doc["agents"]]
    qual = np.array([x[0] for x in per])
    rows = _landmark_rows(page)
    assert sorted(rows) == doc["landmark_ids"]
    for j, lid in enumerate(doc["landmark_ids"]):
        best = float(qual[:, j].max())
        assert float(rows[lid]["quality"]) == pytest.approx(best, abs=6e-4)
        assert rows[lid]["status"] == ("seen" if best > 0 else "unseen")
    assert dict(page.table("summary"))["failsafes"] == "2"


def _chromium() -> str | None:
    return next((p for n in ("chromium-headless-shell", "chromium", "chromium-browser")
                 if (p := shutil.which(n))), None)


def test_the_page_renders_in_headless_chromium(tmp_path: Path,
                                              tower: tuple[Path, float, float]) -> None:
    browser = _chromium()
    if browser is None:
        pytest.skip("no Chromium on this machine (Debian: apt-get install "
                    "chromium-headless-shell); the structural tests above still ran")
    out = tower[0]
    shot = tmp_path / "shot.png"
    subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                    "--window-size=1200,1800", f"--screenshot={shot}",
                    (out / "report.html").as_uri()], check=True, capture_output=True,
                   timeout=120)
    img = np.asarray(Image.open(shot).convert("RGB"))
    assert img.shape[:2] == (1800, 1200)
    # not a blank page: text (dark pixels) and the structure figure's colours are drawn
    assert (img.sum(axis=2) < 150).mean() > 0.002
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 200


def test_a_flight_home_after_completion_does_not_hide_the_coverage_reached() -> None:
    """A recorded flight goes on after completion (home, landing): the summary line and the
    page give the coverage at completion, and the end's only as well (the demo said 7.08
    where the team had reached 9.91)."""
    import dataclasses

    from agent.sim.kinematic import simulate
    from agent.sim.report import result_document
    from agent.sim.webpage import coverage_cell

    res = simulate(load_scenario(scenario_path("cube_6_2")))
    assert res.complete and res.t_complete is not None
    reached = float(res.coverage[res.completion_index()])
    assert reached == pytest.approx(float(res.coverage[-1]))  # a simulation ends there
    assert "at completion" not in res.coverage_line()
    dt = float(res.times[1] - res.times[0])
    later = res.times[-1] + dt * np.arange(1, 4)  # three samples of a flight home, the
    away = np.repeat(-res.directions[-1:], 3, axis=0)  # cameras turned from the landmarks
    landed = dataclasses.replace(
        res, times=np.concatenate((res.times, later)),
        coverage=np.concatenate((res.coverage, [0.9 * reached, 0.8 * reached, 0.7 * reached])),
        positions=np.concatenate((res.positions, np.repeat(res.positions[-1:], 3, axis=0))),
        directions=np.concatenate((res.directions, away)),
        owners=np.concatenate((res.owners, np.repeat(res.owners[-1:], 3, axis=0))),
        vision=np.concatenate((res.vision, np.zeros((3, res.vision.shape[1])))))
    assert landed.quality_line() == res.quality_line() == "15/15 landmarks seen by their owner"
    assert result_document(landed)["checks"]["all_visible_to_owner"]
    unfinished = dataclasses.replace(landed, complete=False)  # judged at the end then
    assert not result_document(unfinished)["checks"]["all_visible_to_owner"]
    assert landed.completion_index() == len(res.times) - 1
    line = landed.coverage_line()
    assert f"-> {reached:.4g} (facing) at completion, t = {res.t_complete:g} s; " \
           f"{0.7 * reached:.4g} at the end" in line
    doc = {"complete": True, "t_complete": res.t_complete,
           "coverage": [[float(t), float(c)] for t, c in zip(landed.times, landed.coverage,
                                                            strict=True)]}
    assert coverage_cell(doc) == (f"{res.coverage[0]:.4g} → {reached:.4g} at completion; "
                                  f"{0.7 * reached:.4g} at the end (t = {later[-1]:g} s)")
    doc["complete"] = False  # not complete: start -> end, as before
    assert coverage_cell(doc) == f"{res.coverage[0]:.4g} → {0.7 * reached:.4g}"
