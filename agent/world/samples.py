"""A structure's sampled landmarks, taken from a prepared file when it holds them: the mesh
landmarks (:func:`agent.structure.sampling.sample_landmarks`, positions [m; world ENU] and
unit normals) depend only on the mesh file's bytes, its placement, the sampling fields and
the seed, so a file written by ``viscover prepare`` (:mod:`agent.world.prepared`) carries
them under :func:`sample_key`, and an agent started with :data:`PREPARED_ENV` naming it reads
them instead of sampling the mesh again. A file without them, or with another key, is not
used (the mesh is sampled); the capture table in it is checked apart, against the resolved
scenario. Positions [m; world ENU]."""

from __future__ import annotations

import hashlib
import os
import zipfile
from pathlib import Path
from typing import TYPE_CHECKING

import msgspec
import numpy as np
from numpy.typing import NDArray

from agent.structure.sampling import sample_landmarks

if TYPE_CHECKING:
    import trimesh

    from agent.config.structure import StructureSpec

Array = NDArray[np.float64]

#: Environment variable naming a prepared file for the agents of a process.
PREPARED_ENV = "VISCOVER_PREPARED"
#: The sampling algorithm's version (agent.structure.sampling); changes when its result may.
SAMPLING_VERSION = 1


def mesh_sha(path: Path) -> str:
    """SHA-256 (hex) of a mesh file's bytes."""
    h = hashlib.sha256()
    with Path(path).open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def sample_key(spec: StructureSpec, seed: int) -> str:
    """SHA-256 (hex) of everything the mesh landmarks of ``spec`` sampled with ``seed``
    depend on: the mesh's bytes, placement, spacing and filters, the seed, the version."""
    doc = {"v": SAMPLING_VERSION, "mesh": mesh_sha(spec.mesh), "position": list(spec.position),
           "yaw": spec.yaw, "scale": spec.scale, "spacing": spec.spacing, "z_min": spec.z_min,
           "min_normal_z": spec.min_normal_z, "region": repr(spec.region), "seed": seed}
    return hashlib.sha256(msgspec.json.encode(doc)).hexdigest()


#: The mesh landmarks this process sampled or read, by key (the last few).
_KEPT: dict[str, tuple[Array, Array]] = {}
KEEP = 4


def mesh_landmarks(mesh: trimesh.Trimesh, spec: StructureSpec, seed: int
                   ) -> tuple[Array, Array]:
    """The landmarks (q, u) (n, 3) sampled on the placed ``mesh`` of ``spec`` with ``seed``:
    from the prepared file :data:`PREPARED_ENV` names when it holds them under this key,
    else sampled (read-only arrays, kept for :func:`samples_of`)."""
    key = sample_key(spec, seed)
    got = _KEPT.get(key) or _from_file(key)
    if got is None:
        q, u = sample_landmarks(mesh, spec.spacing, seed=seed, z_min=spec.z_min,
                                region=spec.region, min_normal_z=spec.min_normal_z)
        q.flags.writeable = u.flags.writeable = False
        got = (q, u)
    _KEPT[key] = got
    while len(_KEPT) > KEEP:
        del _KEPT[next(iter(_KEPT))]
    return got


def _from_file(key: str) -> tuple[Array, Array] | None:
    path = os.environ.get(PREPARED_ENV)
    if not path:
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            if "sample_key" not in z.files or str(z["sample_key"][()]) != key:
                return None
            q = np.asarray(z["sample_q"], dtype=np.float64)
            u = np.asarray(z["sample_u"], dtype=np.float64)
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError):
        return None  # the table's check names what is wrong with the file
    if q.ndim != 2 or q.shape[1:] != (3,) or u.shape != q.shape:
        return None
    q.flags.writeable = u.flags.writeable = False
    return q, u


def samples_of(spec: StructureSpec, seed: int) -> dict[str, NDArray[np.generic]]:
    """The arrays a prepared file stores for ``spec``'s mesh landmarks, when this process
    sampled (or read) them: ``sample_key``, ``sample_q``, ``sample_u``; else none."""
    key = sample_key(spec, seed)
    got = _KEPT.get(key)
    if got is None:
        return {}
    return {"sample_key": np.array(key), "sample_q": got[0], "sample_u": got[1]}
