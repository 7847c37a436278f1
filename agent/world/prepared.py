"""An inspection's preparation in a file: the capture table and route grid built once (by
``viscover prepare`` or ``viscover launch``) and loaded by every agent of the team, instead of
each building the same table itself.

The file is a numpy ``.npz`` archive read with ``allow_pickle=False`` (arrays and strings
only, no code). It holds:

* ``format`` (:data:`FORMAT`) and ``version`` (:data:`VERSION`): what it is and its layout;
* ``digest``: the scenario digest (:func:`agent.config.digest.scenario_digest`: the mission,
  its landmarks and team) and ``mission``, the scenario's name, for the messages;
* ``key``: :func:`preparation_key`, a SHA-256 over everything else the table depends on (the
  landmarks' exact coordinates and view sectors, d_opt, the mission space, the visibility
  model, the inspection spec and camera, the mesh file's bytes and placement, the structure's
  margin) and :data:`TABLE_VERSION`, the algorithm's;
* the table (:class:`~agent.core.inspection.CaptureTable`): ``P``, ``V`` (K, 3) [m; world
  ENU], the captures by rows (``indptr`` (K + 1,), ``indices``: landmark rows, int32),
  ``value`` (K,), ``reason`` (m,);
* the route grid (:class:`~agent.structure.routes.RouteGrid`), if any: ``grid_lo`` (3,) [m],
  ``grid_pitch`` [m], ``grid_free`` (nx, ny, nz) bool;
* with a mesh, its sampled landmarks (``sample_key``, ``sample_q``, ``sample_u``:
  :mod:`agent.world.samples`), so that an agent resolving the scenario reads them instead of
  sampling the mesh again.

A file that is not one, of another version, of another scenario or of other settings is
refused with one line (:class:`PreparedError`, exit status 2) naming the file, what differs
and the command that writes a right one; it is never used silently. Written whole or not at
all (a temporary file renamed).

:data:`PREPARED_ENV` names a prepared file for every :func:`agent.world.prepare.prepare_world`
of a process (``viscover launch`` sets it for its agents).
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import time
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec
import numpy as np
from numpy.typing import NDArray

from agent.config.digest import scenario_digest
from agent.core.capture_rows import CaptureRows
from agent.core.inspection import CaptureTable
from agent.errors import UsageError
from agent.structure.routes import RouteGrid
from agent.world.samples import PREPARED_ENV, mesh_sha, samples_of
from agent.world.tables import mission_tables

if TYPE_CHECKING:
    from agent.config.scenario import Scenario

__all__ = [
    "FORMAT",
    "PREPARED_ENV",
    "TABLE_VERSION",
    "VERSION",
    "PreparedError",
    "check_prepared",
    "load_prepared",
    "preparation_key",
    "prepare_file",
    "prepare_team",
    "save_prepared",
]

FORMAT = "viscover-prepared"
#: The file's layout; a file of another version is refused.
VERSION = 1
#: The capture table's algorithm (agent.structure.inspection); changes when its result may.
TABLE_VERSION = 1

Tables = tuple[CaptureTable, RouteGrid | None]


class PreparedError(UsageError):
    """A prepared file that cannot be used for this scenario (one line: file, why, fix)."""


def _fix(sc: Scenario, src: Path) -> str:
    return f"write it again with `viscover prepare {sc.source} -o {src}`"


def preparation_key(sc: Scenario) -> str:
    """SHA-256 (hex) of what the capture table of the resolved scenario ``sc`` depends on
    beyond its digest (module docstring), with :data:`TABLE_VERSION`."""
    h = hashlib.sha256()
    spec = sc.structure
    mesh = None if spec is None else {
        "sha256": mesh_sha(Path(spec.mesh)), "position": list(spec.position),
        "yaw": spec.yaw, "scale": spec.scale, "margin": spec.margin}
    doc: dict[str, Any] = {
        "table": TABLE_VERSION, "d_opt": sc.d_opt, "visibility": sc.visibility,
        "lo": [repr(float(x)) for x in sc.space.lo], "hi": [repr(float(x)) for x in sc.space.hi],
        "inspection": repr(sc.inspection), "view_cos": sc.view_cos, "mesh": mesh,
    }
    h.update(msgspec.json.encode(doc))
    for arr in (sc.q, sc.u, sc.view_axis):
        if arr is not None:
            h.update(np.ascontiguousarray(arr, dtype="<f8").tobytes())
    h.update(np.asarray(sc.landmark_ids, dtype="<i8").tobytes())
    return h.hexdigest()


def save_prepared(path: str | Path, sc: Scenario, tables: Tables) -> Path:
    """Write ``tables`` of the resolved scenario ``sc`` to ``path`` (whole or not at all);
    returns the path. An unwritable path is a :class:`PreparedError`."""
    out = Path(path)
    table, grid = tables
    rows = table.rows
    arrays: dict[str, NDArray[Any]] = {
        "format": np.array(FORMAT), "version": np.array(VERSION),
        "digest": np.array(scenario_digest(sc)), "key": np.array(preparation_key(sc)),
        "mission": np.array(sc.name),
        "P": table.P, "V": table.V, "indptr": rows.indptr.astype(np.int64),
        "indices": rows.indices.astype(np.int32), "value": table.value,
        "reason": table.reason.astype(np.int8),
    }
    if grid is not None:
        arrays.update(grid_lo=grid.lo, grid_pitch=np.array(grid.pitch), grid_free=grid.free)
    if sc.structure is not None:  # the mesh landmarks, for the agents to skip sampling
        arrays.update(samples_of(dataclasses.replace(sc.structure, sampled=False), sc.seed))
    part = out.with_name(f".{out.name}.{os.getpid()}.part")
    try:
        with part.open("wb") as fh:
            np.savez(fh, **arrays)  # type: ignore[arg-type]
        os.replace(part, out)
    except OSError as e:
        part.unlink(missing_ok=True)
        raise PreparedError(f"{out}: cannot write the prepared file: {e.strerror or e}; "
                            "choose another path") from None
    return out


def _text(z: Any, name: str) -> str:
    return str(z[name][()])


def _table(z: Any, m: int) -> CaptureTable:
    """The table of an open archive over m landmarks, its shapes checked (ValueError)."""
    indptr, indices = z["indptr"].astype(np.intp), z["indices"].astype(np.intp)
    P, V, value, reason = z["P"], z["V"], z["value"], z["reason"]
    K = P.shape[0]
    if not (P.shape == V.shape == (K, 3) and value.shape == (K,) and indptr.shape == (K + 1,)
            and indptr[0] == 0 and indptr[-1] == indices.size
            and (np.diff(indptr) >= 0).all()
            and (indices.size == 0 or (indices.min() >= 0 and indices.max() < m))):
        raise ValueError("inconsistent table shapes")
    return CaptureTable(P, V, CaptureRows(indptr, indices, m), value,
                        reason.astype(np.int8))


def _check(z: Any, src: Path, sc: Scenario) -> None:
    """Refuse the open archive ``z`` (read from ``src``) unless it is a prepared file of
    this version for ``sc`` with its settings (a PreparedError naming what differs)."""
    if _text(z, "format") != FORMAT:
        raise KeyError("format")
    version = int(z["version"][()])
    if version != VERSION:
        raise PreparedError(f"{src}: a prepared file of version {version}, this viscover "
                            f"reads version {VERSION}; {_fix(sc, src)}")
    digest, mission = _text(z, "digest"), _text(z, "mission")
    want = scenario_digest(sc)
    if digest != want:
        raise PreparedError(f"{src}: prepared for mission {mission!r} (scenario digest "
                            f"{digest}), not for {sc.source} (digest {want}); "
                            f"{_fix(sc, src)}")
    if _text(z, "key") != preparation_key(sc):
        raise PreparedError(f"{src}: prepared for this scenario's landmarks but other "
                            "settings (exact coordinates, d_opt, space, visibility, "
                            "inspection, camera, mesh or its placement, or an older table "
                            f"algorithm); {_fix(sc, src)}")


def _open_error(src: Path, sc: Scenario, e: BaseException) -> PreparedError:
    if isinstance(e, FileNotFoundError):
        return PreparedError(f"{src}: no such prepared file; {_fix(sc, src)}")
    if isinstance(e, IsADirectoryError):
        return PreparedError(f"{src}: is a directory, expected a prepared .npz file")
    return PreparedError(f"{src}: not a viscover prepared file; {_fix(sc, src)}")


_READ_ERRORS = (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError)


def check_prepared(path: str | Path, sc: Scenario) -> None:
    """Whether ``path`` is a prepared file for ``sc`` (only its header is read): returns
    quietly, or raises the :class:`PreparedError` :func:`load_prepared` would."""
    src = Path(path)
    try:
        with np.load(src, allow_pickle=False) as z:
            _check(z, src, sc)
    except PreparedError:
        raise
    except _READ_ERRORS as e:
        raise _open_error(src, sc, e) from None


def prepare_file(sc: Scenario, path: str | Path, progress: Callable[[str], None] | None = None
                 ) -> bool:
    """Make ``path`` the prepared file of the resolved inspection scenario ``sc``: kept when
    it already is one (True), else (missing, stale, of another scenario) built and written
    (False)."""
    try:
        check_prepared(path, sc)
        return True
    except PreparedError:
        pass
    save_prepared(path, sc, mission_tables(sc) if progress is None else
                  mission_tables(sc, progress))
    return False


def prepare_team(sc: Scenario, run_dir: Path, say: Callable[[str], None]) -> dict[str, str]:
    """``viscover launch``'s preparation: an inspection's tables built once for the whole
    team into ``run_dir``/prepared.npz (kept when already this scenario's: a resumed run);
    returns the environment that names it to the agents ({} for a coverage mission)."""
    if sc.inspection is None:
        return {}
    path = run_dir / "prepared.npz"
    start = time.monotonic()
    kept = prepare_file(sc, path)
    say(f"launch: capture table {'kept' if kept else 'prepared'} once for the team: {path} "
        f"({time.monotonic() - start:.1f} s)")
    return {PREPARED_ENV: str(path.resolve())}


def load_prepared(path: str | Path, sc: Scenario) -> Tables:
    """The capture table and route grid of the resolved scenario ``sc`` from the prepared
    file ``path``; a :class:`PreparedError` (one line) when it is not one, or not this
    scenario's with these settings."""
    src = Path(path)
    try:
        with np.load(src, allow_pickle=False) as z:
            _check(z, src, sc)
            table = _table(z, len(sc.landmark_ids))
            grid = None if "grid_free" not in z.files else RouteGrid.from_free(
                z["grid_lo"], float(z["grid_pitch"][()]), z["grid_free"])
    except PreparedError:
        raise
    except _READ_ERRORS as e:
        raise _open_error(src, sc, e) from None
    return table, grid
