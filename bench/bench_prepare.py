"""Preparation benchmarks: what an inspection costs before take-off, and what an
agent then waits for.

- ``prepare``: the landmarks sampled on the mesh, the candidate viewpoints and the capture
  table and route grid built (:func:`agent.world.tables.mission_tables`), then written to a
  prepared file and loaded back (:mod:`agent.world.prepared`), each in a fresh child process
  so that its peak memory (``ru_maxrss``, with the interpreter and imports, ``base_mb``
  before any work) is this size's alone; ``cpu_s`` the child's CPU time (user + system; the
  wall times count the other processes of a shared machine too). Two series on the U-shaped
  building of the inspection benchmark (d_opt 6 m, occlusion, 90°×70° field of view,
  incidence ≤ 75°): ``scaled``, the building scaled by √(m / 1000) with landmarks every
  0.8 m, so that the landmarks an image holds stay the same and m grows with the surface
  (goal: linear; 10⁴ in ≤ 10 s and 1 GB, 10⁵ in ≤ 2 min and 4 GB); ``denser``, the same
  building with landmarks ever closer, so that an image holds ever more of them (the
  captures, and so the work, grow with m²).
- ``agent_first_state``: one ``viscover agent`` process of an inspection scenario (the
  gabled house; the scaled series' 10⁴ landmarks), from its start to its first published
  state on a loopback router: building the table itself, or loading the file
  ``viscover prepare`` wrote (``prepare_s``: that command's own time); then its peak
  resident memory after flying ``FLY_S`` more (``agent_peak_mb``: what a companion computer
  needs).
- ``scenario_load``: :func:`agent.config.parse.parse_scenario` of a scenario with m explicit
  ``[[landmarks]]`` (ids left to the parser) up to the 16 MiB file limit (goal: linear;
  before: 10k 3.2 s, 20k 9.4 s, 40k 26.8 s, 200k never finished).

Run: ``python -m bench.bench_prepare [--sizes 1000,10000,100000] [--series scaled,denser]
[--skip first_state,load]``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, TextIO

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SIZES = (1_000, 10_000, 100_000)
SERIES = ("scaled", "denser")
#: The denser series stops here (its cost grows with m²).
DENSER_MAX = 10_000
SPACING = 0.8  #: [m] the scaled series' landmark spacing (about 1,000 at scale 1)
LOAD_SIZES = (10_000, 100_000, 200_000)
FLY_S = 10.0  #: [wall s] an agent flies after its first state before its memory is read


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    return env


def scene_text(series: str, m: int) -> str:
    """The TOML of the U building with about ``m`` landmarks (module docstring)."""
    from bench.inspection.scenes import SCENES, scaled_scene
    from bench.inspection.scenes import scene_text as base_text

    scene = next(s for s in SCENES if s.kind == "concave")
    scale = math.sqrt(m / 1000.0) if series == "scaled" else 1.0
    spacing = SPACING if series == "scaled" else SPACING * math.sqrt(1000.0 / m)
    big = scaled_scene(scene, scale, spacing)
    starts = np.array([[big.lo[0] + 1.0, big.lo[1] + 1.0, big.lo[2] + 1.0],
                       [big.hi[0] - 1.0, big.lo[1] + 1.0, big.lo[2] + 1.0]])
    return base_text(big, starts)


def _child(series: str, m: int, out: Path) -> None:
    """In a fresh process: resolve, build, save, load; one JSON line on stdout."""
    from agent.config.parse import parse_scenario
    from agent.world.prepared import load_prepared, save_prepared
    from agent.world.structure import resolve_structure
    from agent.world.tables import mission_tables

    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t0 = time.perf_counter()
    sc = resolve_structure(parse_scenario(scene_text(series, m), str(out.with_suffix(".toml"))))
    t1 = time.perf_counter()
    tables = mission_tables(sc)
    t2 = time.perf_counter()
    save_prepared(out, sc, tables)
    t3 = time.perf_counter()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    del tables
    t4 = time.perf_counter()
    table, _ = load_prepared(out, sc)
    t5 = time.perf_counter()
    use = resource.getrusage(resource.RUSAGE_SELF)
    print(json.dumps({
        "landmarks": len(sc.landmark_ids), "viewpoints": int(table.P.shape[0]),
        "captures": table.rows.nnz, "sample_s": round(t1 - t0, 2),
        "table_s": round(t2 - t1, 2), "prepare_s": round(t2 - t0, 2),
        "save_s": round(t3 - t2, 2), "load_s": round(t5 - t4, 2),
        "file_mb": round(out.stat().st_size / 2**20, 1), "base_mb": round(base),
        "peak_mb": round(peak), "cpu_s": round(use.ru_utime + use.ru_stime, 1)}))


def prepare_cost(series: str, m: int, timeout_s: float = 900.0) -> dict[str, Any]:
    """One ``prepare`` row: the child's measurements of series ``series`` at about m."""
    tmp = Path(tempfile.mkdtemp(prefix="viscover-prepare-"))
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "bench.bench_prepare", "--child", series, str(m),
             str(tmp / "scene.prepared.npz")], capture_output=True, text=True, env=_env(),
            cwd=ROOT, timeout=timeout_s, check=False)
        row: dict[str, Any] = {"bench": "prepare", "series": series, "target": m}
        if proc.returncode != 0:
            row["error"] = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        else:
            row.update(json.loads(proc.stdout.strip().splitlines()[-1]))
    except subprocess.TimeoutExpired:
        row = {"bench": "prepare", "series": series, "target": m,
               "error": f"over {timeout_s:g} s"}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    row["load_1min"] = round(os.getloadavg()[0], 2)
    return row


def first_state(scenario: Path, prepared: bool, timeout_s: float = 180.0) -> dict[str, Any]:
    """Seconds from one agent's start to its first published state (module docstring)."""
    from agent.config.parse import load_scenario
    from agent.net.router import client_config, start_router_process, stop_router_process
    from agent.net.transport import ZenohTransport
    from agent.wire import keys
    from agent.world.prepared import PREPARED_ENV

    tmp = Path(tempfile.mkdtemp(prefix="viscover-first-"))
    env = _env()
    row: dict[str, Any] = {"bench": "agent_first_state", "scenario": scenario.name,
                           "prepared": prepared}
    if prepared:
        t = time.perf_counter()
        subprocess.run([sys.executable, "-m", "agent.cli", "prepare", str(scenario), "-o",
                        str(tmp / "p.npz"), "--quiet"], env=env, cwd=ROOT, check=True,
                       capture_output=True)
        row["prepare_s"] = round(time.perf_counter() - t, 2)
        env[PREPARED_ENV] = str(tmp / "p.npz")
    aid = load_scenario(scenario).agents[0].id
    mission = f"first{os.getpid()}"
    router, ep = start_router_process()
    tp = ZenohTransport(client_config(ep), None, "bench-first")
    heard = threading.Event()
    sub = tp.subscribe(keys.all_agents(mission, "state"), lambda _k, _p: heard.set())
    t0 = time.monotonic()
    proc = subprocess.Popen(
        [sys.executable, "-m", "agent.cli", "agent", "--id", aid, "--scenario", str(scenario),
         "--connect", ep, "--mission", mission, "--state-dir", str(tmp / aid),
         "--rate-scale", "10"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        env=env, cwd=ROOT)
    try:
        got = heard.wait(timeout_s)
        row["first_state_s"] = round(time.monotonic() - t0, 2) if got else None
        if got:  # then it flies its part for a while: its peak memory (a companion computer)
            time.sleep(FLY_S)
            row["agent_peak_mb"] = _peak_mb(proc.pid)
    finally:
        proc.terminate()
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        sub.undeclare()
        tp.close()
        stop_router_process(router)
        shutil.rmtree(tmp, ignore_errors=True)
    row["load_1min"] = round(os.getloadavg()[0], 2)
    return row


def _peak_mb(pid: int) -> float | None:
    """The peak resident memory [MB] of live process ``pid`` (Linux ``VmHWM``), or None."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return round(int(line.split()[1]) / 1024, 1)
    except OSError:
        return None
    return None


def explicit_text(m: int) -> str:
    """A scenario of m explicit landmarks (no ids: the parser numbers them), one agent."""
    rows = "".join(f"[[landmarks]]\nposition = [{0.01 * i:.2f}, 0.0, 1.0]\n"
                   "normal = [0.0, -1.0, 0.0]\n" for i in range(m))
    owned = ", ".join(str(i) for i in range(1, m + 1))
    return (f'name = "explicit"\ndims = 3\nd_opt = 1.0\nduration = 10.0\n{rows}'
            f'[[agents]]\nid = "A"\nposition = [0.0, -3.0, 1.0]\nlandmarks = [{owned}]\n')


def load_cost(m: int) -> dict[str, Any]:
    """One ``scenario_load`` row: parse time of m explicit landmarks (best of 2)."""
    from agent.config.parse import parse_scenario

    text = explicit_text(m)
    best = math.inf
    for _ in range(2):
        t = time.perf_counter()
        sc = parse_scenario(text, "explicit.toml")
        best = min(best, time.perf_counter() - t)
    assert sc.landmark_ids[-1] == m
    return {"bench": "scenario_load", "landmarks": m, "file_mb": round(len(text) / 2**20, 2),
            "load_s": round(best, 2), "us_per_landmark": round(1e6 * best / m, 1),
            "load_1min": round(os.getloadavg()[0], 2)}


def _emit(out: TextIO, row: dict[str, Any]) -> None:
    out.write(json.dumps(row) + "\n")
    out.flush()


def run(out: TextIO, sizes: tuple[int, ...] = SIZES, series: tuple[str, ...] = SERIES,
        skip: tuple[str, ...] = ()) -> None:
    """Every row of the module docstring."""
    for s in series:
        for m in sizes:
            if s == "denser" and m > DENSER_MAX:
                continue
            _emit(out, prepare_cost(s, m))
    if "first_state" not in skip:
        house = ROOT / "scenarios" / "inspect_gabled_house.toml"
        for prepared in (False, True):
            _emit(out, first_state(house, prepared))
        with tempfile.TemporaryDirectory(prefix="viscover-scaled-") as tmp:
            big = Path(tmp) / "scaled_10000.toml"  # the scaled series' 10⁴ landmarks
            big.write_text(scene_text("scaled", 10_000), encoding="utf-8")
            _emit(out, first_state(big, True))
    if "load" not in skip:
        for m in LOAD_SIZES:
            _emit(out, load_cost(m))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--child", nargs=3, metavar=("SERIES", "M", "OUT"), help=argparse.SUPPRESS)
    ap.add_argument("--sizes", default=",".join(map(str, SIZES)))
    ap.add_argument("--series", default=",".join(SERIES))
    ap.add_argument("--skip", default="", help="first_state,load")
    args = ap.parse_args(argv)
    if args.child:
        _child(args.child[0], int(args.child[1]), Path(args.child[2]))
        return 0
    run(sys.stdout, tuple(int(x) for x in args.sizes.split(",")),
        tuple(args.series.split(",")), tuple(filter(None, args.skip.split(","))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
