"""Bounded input (agent.config.limits, agent.structure.mesh): every size a scenario file
controls is checked before anything of that size is allocated, and a bad mesh file is one
line. The commands run as subprocesses under a 2 GiB address-space limit, so a regression
fails here (MemoryError, exit 1) instead of swapping the machine."""

from __future__ import annotations

import os
import resource
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

from agent.config.limits import MAX_SCENARIO_BYTES
from agent.config.parse import parse_scenario
from agent.config.scenario import ScenarioError
from agent.structure.mesh import MAX_MESH_BYTES, MAX_MESH_TRIANGLES, load_mesh

ROOT = Path(__file__).resolve().parent.parent
MEMORY_LIMIT = 2 * 1024**3  # [bytes] of address space for each command run here

HEAD_2D = "dims = 2\nd_opt = 1.0\nduration = 10.0\n"
AGENT_2D = '[[agents]]\nid = "A"\nposition = [0.0, 0.0]\n'
MESH_TOML = """\
dims = 3
d_opt = 2.0
duration = 10.0

[structure]
mesh = "{mesh}"
spacing = {spacing}

[[agents]]
id = "A"
position = [30.0, 0.0, 5.0]
"""


def _limit_memory() -> None:
    """In the child before exec: cap its address space."""
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


def viscover(*argv: str, timeout: float = 60.0) -> tuple[subprocess.CompletedProcess[str],
                                                         float]:
    """Run ``viscover ARGV`` under the memory limit: (finished process, seconds taken)."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    t0 = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "agent.cli", *argv], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=timeout,
                          preexec_fn=_limit_memory)
    return done, time.monotonic() - t0


def one_error(done: subprocess.CompletedProcess[str]) -> str:
    """The single stderr line of a usage error (exit 2), without the ``viscover: error:``."""
    assert done.returncode == 2, (done.returncode, done.stderr[-2000:])
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert lines[0].startswith("viscover: error: "), lines[0]
    return lines[0].removeprefix("viscover: error: ")


def _error(text: str, source: str = "s.toml") -> str:
    with pytest.raises(ScenarioError) as info:
        parse_scenario(text, source)
    return str(info.value)


# -- the scenario file's own counts ----------------------------------------------------------


def test_twenty_thousand_agents_fail_fast_in_bounded_memory(tmp_path: Path) -> None:
    """Was: the n × n distance check of 20,000 agents asked for 8.94 GiB (MemoryError,
    exit 1, a traceback)."""
    agents = "".join(f'[[agents]]\nid = "a{i}"\nposition = [{i * 2.0}, 0.0]\n'
                     for i in range(20_000))
    path = tmp_path / "crowd.toml"
    path.write_text(HEAD_2D + '[[generators]]\nkind = "polygon"\nsides = 3\nside = 1.0\n'
                    + agents.replace("\n", "\nlandmarks = [1, 2, 3]\n", 1))
    assert path.stat().st_size > 1_000_000
    done, took = viscover("scenario", "check", str(path))
    assert one_error(done) == (f"{path}: agents: 20,000 agents, more than the limit of 256; "
                               "split the team into several scenarios")
    assert took < 20.0


@pytest.mark.parametrize(("generator", "message"), [
    ('kind = "polygon"\nsides = 100000000\nside = 0.5',
     "generators[0].sides: gives 100,000,000 landmarks, more than the limit of 1,000,000 in "
     "a scenario; use fewer sides"),
    ('kind = "box"\ncenter = [0.0, 0.0, 1.0]\nsize = 1.0\ngrid = [100000, 100000]',
     "generators[0].grid: gives 60,000,000,000 landmarks, more than the limit of 1,000,000 "
     "in a scenario; use a smaller grid or fewer faces"),
    ('kind = "box"\ncenter = [0.0, 0.0, 1.0]\nsize = 1.0\nfaces = ["+z"]\ncount = 2000000',
     "generators[0].count: gives 2,000,000 landmarks, more than the limit of 1,000,000 in a "
     "scenario; use a smaller count or fewer faces"),
    ('kind = "cylinder"\ncenter = [0.0, 0.0, 0.0]\nradius = 1.0\nheight = 1.0\n'
     'around = 100000\nrows = 100000',
     "generators[0].around: gives 10,000,000,000 landmarks, more than the "
     "limit of 1,000,000 in a scenario; use fewer around or rows"),
])
def test_generator_counts_are_bounded_before_allocating(generator: str, message: str) -> None:
    """Was: numpy asked for the arrays (ArrayMemoryError, or the machine swapped)."""
    text = ("dims = 3\nd_opt = 1.0\nduration = 10.0\n[[generators]]\n" + generator
            + '\n[[agents]]\nid = "A"\nposition = [9.0, 0.0, 0.0]\n')
    assert _error(text) == f"s.toml: {message}"


def test_generators_count_together() -> None:
    """The limit is on all landmarks: two generators of 600,000 each fail at the second.
    Was: all 1.2 million generated, then refused for another reason (no owner)."""
    gen = '[[generators]]\nkind = "polygon"\nsides = 600000\nside = 0.001\n'
    assert _error(HEAD_2D + gen + gen + AGENT_2D) == (
        "s.toml: generators[1].sides: gives 600,000 landmarks (600,000 before them), more "
        "than the limit of 1,000,000 in a scenario; use fewer sides")


def test_huge_sides_in_check_and_observe_is_one_line(tmp_path: Path) -> None:
    """`scenario check` and `observe` parse the same file: one line, exit 2, in seconds and
    under 2 GiB. Was: MemoryError traceback (763 MiB for one array, then more), exit 1."""
    path = tmp_path / "big.toml"
    path.write_text(HEAD_2D + '[[generators]]\nkind = "polygon"\nsides = 100000000\n'
                    'side = 0.5\n' + AGENT_2D)
    want = (f"{path}: generators[0].sides: gives 100,000,000 landmarks, more than the limit "
            "of 1,000,000 in a scenario; use fewer sides")
    for argv in (("scenario", "check", str(path)),
                 ("observe", "--scenario", str(path), "--connect", "tcp/127.0.0.1:9",
                  "--connect-wait", "0.1", "--timeout", "1")):
        done, took = viscover(*argv)
        assert one_error(done) == want, argv
        assert took < 20.0, argv


def test_landmark_ids_are_bounded_and_listed_briefly() -> None:
    """Ids above 2^53 - 1 are refused (was: accepted, then overflowed int64 on the wire);
    an unknown id lists far-apart known ids without building the range between them (was:
    MemoryError from a list of 10^15 numbers)."""
    lm = "[[landmarks]]\nid = {}\nposition = [{}, 1.0]\nnormal = [0.0, 1.0]\n"
    far = HEAD_2D + lm.format(0, 0.0) + lm.format(10**15, 1.0)
    assert _error(far + AGENT_2D + "landmarks = [5]\n") == (
        "s.toml: agents[0].landmarks[0]: unknown landmark id 5; known ids are "
        "0, 1000000000000000")
    assert _error(HEAD_2D + lm.format(2**63, 0.0) + AGENT_2D + f"landmarks = [{2**63}]\n") == (
        f"s.toml: landmarks[0].id: must be at most 2^53 - 1 = {2**53 - 1}, got {2**63}")


def test_orphan_listing_is_short() -> None:
    """Was: every one of the 1,000 orphan ids in the line."""
    text = HEAD_2D + '[[generators]]\nkind = "polygon"\nsides = 1000\nside = 0.1\n' + AGENT_2D
    assert _error(text) == (
        "s.toml: agents: landmark(s) [" + ", ".join(map(str, range(1, 21)))
        + ", ... (1,000 in all)] are assigned to no agent; add them to an agent's "
        "`landmarks` list")


def test_scenario_file_size_is_bounded(tmp_path: Path) -> None:
    """Was: a 17 MiB file (here one long comment) read and parsed whole, and accepted."""
    path = tmp_path / "padded.toml"
    with path.open("w") as fh:
        fh.write(HEAD_2D + '[[generators]]\nkind = "polygon"\nsides = 3\nside = 1.0\n'
                 + AGENT_2D + "landmarks = [1, 2, 3]\n# ")
        fh.write("x" * (MAX_SCENARIO_BYTES + 2**20) + "\n")
    done, _ = viscover("scenario", "check", str(path))
    assert one_error(done) == (f"{path}: larger than the limit of 16 MiB for a scenario file; "
                               "is this a TOML scenario file?")


# -- the mesh: read and sampled by `scenario check`, bounded before sampling -------------------


@pytest.fixture
def mesh_dir(tmp_path: Path) -> Path:
    """A folder with a 10 m box mesh (600 m² of surface), ``box.stl``."""
    trimesh.creation.box((10.0, 10.0, 10.0)).export(tmp_path / "box.stl")
    return tmp_path


def _mesh_scenario(folder: Path, mesh: str, spacing: float = 2.0) -> Path:
    path = folder / "s.toml"
    path.write_text(MESH_TOML.format(mesh=mesh, spacing=spacing))
    return path


def test_tiny_spacing_is_refused_before_sampling(mesh_dir: Path) -> None:
    """Was: `scenario check` said "ok" (the mesh was not sampled), and a run asked for
    hundreds of gigabytes of candidate points."""
    path = _mesh_scenario(mesh_dir, "box.stl", spacing=0.001)
    done, took = viscover("scenario", "check", str(path))
    assert one_error(done) == (
        f"{path}: structure.spacing: 0.001 m on 600 m² of surface gives about 600,000,000 "
        "landmarks (area / spacing²), more than the limit of 200,000; use spacing >= "
        "0.0548 m or a region of interest")
    assert took < 20.0


def test_random_bytes_stl_is_one_line(mesh_dir: Path) -> None:
    """Was: `scenario check` said "ok"; a run said "cannot read mesh (No module named
    'charset_normalizer')" (trimesh's fallback for text that is not UTF-8)."""
    stl = mesh_dir / "noise.stl"
    stl.write_bytes(np.random.default_rng(0).bytes(4000))
    count = struct.unpack("<I", stl.read_bytes()[80:84])[0]
    path = _mesh_scenario(mesh_dir, "noise.stl")
    done, _ = viscover("scenario", "check", str(path))
    assert one_error(done) == (
        f"{path}: structure.mesh: {stl}: cannot read mesh (not a binary STL: its header "
        f"announces {count:,} triangles, {84 + 50 * count:,} bytes, the file has 4,000; "
        "nor ASCII STL: not UTF-8 text); check the file is a mesh (STL, OBJ, PLY)")


def test_random_bytes_obj_is_one_line(tmp_path: Path) -> None:
    """Was: "cannot read mesh (No module named 'charset_normalizer')"."""
    obj = tmp_path / "noise.obj"
    obj.write_bytes(b"v 0 0 0\n\xff\xfe\x00garbage")
    with pytest.raises(ValueError) as info:
        load_mesh(obj)
    assert str(info.value) == (f"{obj}: cannot read mesh (not UTF-8 text at byte 8); check "
                               "the file is a mesh (STL, OBJ, PLY)")


def test_empty_mesh_fails_check(mesh_dir: Path) -> None:
    """Was: "ok" from `scenario check`; the empty mesh was found only when a run started."""
    (mesh_dir / "empty.stl").write_text("solid empty\nendsolid empty\n")
    path = _mesh_scenario(mesh_dir, "empty.stl")
    done, _ = viscover("scenario", "check", str(path))
    assert one_error(done) == (f"{path}: structure.mesh: {mesh_dir / 'empty.stl'}: mesh has "
                               "no triangles")


def test_good_mesh_check_reports_sampled_landmarks(mesh_dir: Path) -> None:
    """A good mesh scenario is still "ok", with the landmarks sampled on it counted."""
    path = _mesh_scenario(mesh_dir, "box.stl")
    done, _ = viscover("scenario", "check", str(path))
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"ok  {path}: s: 3-D, ") and \
        "structure box.stl (landmarks every 2 m)" in done.stdout, done.stdout


def test_mesh_file_bounds_are_read_from_the_header(tmp_path: Path) -> None:
    """A binary STL announcing more triangles than the limit, and a mesh file over the size
    limit (both sparse: nothing is written or read but the header). Was: trimesh read them
    whole (a 50 MB array, then about 700 MB of mesh)."""
    stl = tmp_path / "many.stl"
    n = MAX_MESH_TRIANGLES + 1
    with stl.open("wb") as fh:
        fh.write(b"\0" * 80 + struct.pack("<I", n))
        fh.truncate(84 + 50 * n)
    with pytest.raises(ValueError) as info:
        load_mesh(stl)
    assert str(info.value) == (f"{stl}: 1,000,001 triangles, more than the limit of "
                               "1,000,000 for a structure mesh; simplify the mesh")
    big = tmp_path / "big.obj"
    with big.open("wb") as fh:
        fh.truncate(MAX_MESH_BYTES + 1)
    with pytest.raises(ValueError) as info:
        load_mesh(big)
    assert str(info.value) == (f"{big}: {MAX_MESH_BYTES + 1:,} bytes, more than the limit of "
                               "64 MiB for a structure mesh; simplify the mesh")


def test_tiny_margin_is_refused_where_the_structure_is_voxelised(mesh_dir: Path) -> None:
    """Coverage moves voxelise the structure at the margin: 1 cm on a 10 m box would be 8e9
    voxels. Was: accepted, the voxels asked for when the coverage moves start."""
    path = _mesh_scenario(mesh_dir, "box.stl")
    path.write_text(path.read_text().replace("dims = 3", 'dims = 3\nstrategy = "potential"')
                    .replace("spacing = 2.0", "spacing = 2.0\nmargin = 0.01"))
    done, _ = viscover("scenario", "check", str(path))
    assert one_error(done) == (
        f"{path}: structure.margin: 0.01 m on a structure of 10 × 10 × 10 m needs "
        "8,012,006,001 voxels of margin / 2 (viewpoint keep-out, routes), more than the "
        "limit of 10,000,000; use margin >= 0.0935 m")
