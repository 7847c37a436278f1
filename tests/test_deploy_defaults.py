"""Safe deployment defaults: the ground station names its pose source (no default, in the
CLI and in its systemd unit), the example environment file names only files the installer
makes, and a drone installs without the optional extras (ground, mocap, occlusion-fast).

The extras are made unimportable in a subprocess (``sys.modules[name] = None``), which is what
a drone-only install (``pip install viscover``, ``deploy/install.sh --drone``) looks like.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from agent.net.pki import DEFAULT_HOSTS, TeamPlan, make_team
from agent.net.router import start_router_process, stop_router_process
from tests.conftest import ROOT, repo_env, scenario_path

CUBE = scenario_path("cube_6_2")
DEPLOY = ROOT / "deploy"
UNIT = DEPLOY / "systemd" / "viscover-groundstation.service"
ENV_EXAMPLE = DEPLOY / "viscover.env.example"

NO_SOURCE = ("viscover: error: --source is required: sim (simulated vehicles, rehearsals) or "
             "motioncapture (real drones); the systemd unit takes it from VISCOVER_GS_SOURCE "
             "in /etc/viscover/viscover.env\n")
NO_MOCAP = ("viscover: error: --source motioncapture needs the package motioncapture, which is "
            "not installed: install viscover[mocap] (pip install 'viscover[mocap]')\n")
SLOW_CASTER = ("occlusion: embreex is not installed, using trimesh's slower pure-numpy ray "
               "caster (pip install 'viscover[occlusion-fast]' where a wheel exists)")
#: What a drone-only install lacks: the extras' packages.
EXTRA_PACKAGES = ("matplotlib", "mpl_toolkits", "foxglove", "mcap", "rich", "motioncapture",
                  "embreex")
#: Runs ``agent.cli.main`` on argv with the given packages unimportable.
BLOCKED_MAIN = ("import sys\nfor n in sys.argv[1].split(','):\n    sys.modules[n] = None\n"
                "from agent.cli import main\nsys.exit(main(sys.argv[2:]))\n")


def _viscover(*argv: str, blocked: tuple[str, ...] = (), timeout: float = 60.0
              ) -> subprocess.CompletedProcess[str]:
    """``viscover ARGV`` in a subprocess with ``blocked`` packages unimportable."""
    return subprocess.run([sys.executable, "-c", BLOCKED_MAIN, ",".join(blocked), *argv],
                          capture_output=True, text=True, env=repo_env(), timeout=timeout,
                          cwd=ROOT)


# -- the ground station's source ---------------------------------------------------------------


@pytest.mark.parametrize("source", [None, ""])
def test_groundstation_without_source_is_refused_in_one_line(source: str | None) -> None:
    """No default source: missing (or empty, as an unset VISCOVER_GS_SOURCE gives the unit)
    is refused before anything starts, in one line naming the choices, exit 2."""
    src = [] if source is None else ["--source", source]
    r = _viscover("groundstation", *src, "--scenario", str(CUBE),
                  "--connect", "tcp/127.0.0.1:9", "--connect-wait", "0")
    assert (r.returncode, r.stderr) == (2, NO_SOURCE)
    assert r.stdout == ""


def _env_file(text: str) -> dict[str, str]:
    """The assignments of an environment file (comments and blank lines skipped)."""
    out = {}
    for line in text.splitlines():
        if line.strip() and not line.lstrip().startswith("#"):
            name, _, value = line.partition("=")
            out[name.strip()] = value.strip()
    return out


def _systemd_argv(exec_start: str, env: dict[str, str]) -> list[str]:
    """ExecStart's argv as systemd builds it: ``${X}`` is exactly one argument (empty when
    unset), ``$X`` is split at whitespace (none when empty)."""
    argv: list[str] = []
    for word in shlex.split(exec_start):
        if m := re.fullmatch(r"\$\{(\w+)\}", word):
            argv.append(env.get(m[1], ""))
        elif m := re.fullmatch(r"\$(\w+)", word):
            argv += env.get(m[1], "").split()
        else:
            argv.append(word)
    return argv


def test_unit_names_its_source_from_the_env_file_and_refuses_without() -> None:
    """The unit passes ``--source ${VISCOVER_GS_SOURCE}`` and sets no default of its own; the
    example env file leaves it empty (with its comment), so the installed unit refuses in one
    line and is not restarted for it (exit 2)."""
    unit = UNIT.read_text()
    (exec_start,) = re.findall(r"^ExecStart=(.*)$", unit, re.M)
    assert "--source ${VISCOVER_GS_SOURCE}" in exec_start
    assert not re.search(r"^(Environment=|DefaultEnvironment=).*VISCOVER_GS_SOURCE", unit, re.M)
    assert ":-" not in exec_start  # no ${VISCOVER_GS_SOURCE:-sim}-style default
    assert re.search(r"^RestartPreventExitStatus=2$", unit, re.M)
    text = ENV_EXAMPLE.read_text()
    env = _env_file(text)
    assert env["VISCOVER_GS_SOURCE"] == ""
    comment = text[:text.index("VISCOVER_GS_SOURCE=")].rsplit("\n\n", 1)[-1]
    assert "motioncapture" in comment and "sim" in comment
    env.update(VISCOVER_SCENARIO=str(CUBE),
               VISCOVER_ZENOH=str(ROOT / "broker_config" / "agent.json5"))
    argv = _systemd_argv(exec_start, env)
    assert argv[0] == "/opt/viscover/.venv/bin/viscover" and argv[1] == "groundstation"
    r = _viscover(*argv[1:])
    assert (r.returncode, r.stderr) == (2, NO_SOURCE)


# -- the installer and the example env file --------------------------------------------------


def _install(root: Path, *mode: str) -> subprocess.CompletedProcess[str]:
    """``deploy/install.sh MODE --root ROOT --skip-venv``: files only, nothing system-wide."""
    script = DEPLOY / "install.sh"
    # Never run an installer without staging: it would install on this machine.
    assert "--root" in script.read_text() and "--skip-venv" in script.read_text()
    return subprocess.run(["bash", str(script), *mode, "--root", str(root), "--skip-venv"],
                          capture_output=True, text=True, timeout=120)


def test_env_file_names_only_files_install_sh_makes(tmp_path: Path) -> None:
    """Every path the installed viscover.env names exists after ``install.sh`` (both modes);
    the secured profile's paths, commented out, are files deploy/make-certs.py writes."""
    for mode in ("--drone", "--ground"):
        root = tmp_path / mode.strip("-")
        r = _install(root, mode)
        assert r.returncode == 0, r.stderr
        env = _env_file((root / "etc/viscover/viscover.env").read_text())
        paths = [v for v in env.values() if v.startswith("/")]
        assert len(paths) >= 3, env
        missing = [p for p in paths if not (root / p.lstrip("/")).exists()]
        assert missing == [], f"{mode}: viscover.env names files install.sh does not make"
    units = {m: sorted(p.name for p in (tmp_path / m / "etc/systemd/system").iterdir())
             for m in ("drone", "ground")}
    assert units == {"drone": ["viscover-agent@.service"],
                     "ground": ["viscover-groundstation.service", "viscover-router.service"]}
    assert "VISCOVER_GS_SOURCE" in _install(tmp_path / "again", "--ground").stdout
    # The secured profile: commented out, pointing at make-certs.py's files.
    secured = dict(re.findall(r"^#(VISCOVER_\w+)=(\S+)$", ENV_EXAMPLE.read_text(), re.M))
    assert secured == {"VISCOVER_ROUTER_CONFIG": "/etc/viscover/certs/router.json5",
                       "VISCOVER_TLS_DIR": "/etc/viscover/certs"}
    team = tmp_path / "team"
    make_team(TeamPlan(out=team, drones=["A"], hosts=DEFAULT_HOSTS,
                       paths_dir=Path("/etc/viscover/certs")))
    assert (team / "router.json5").is_file()
    assert "/etc/viscover/certs/router.pem" in (team / "router.json5").read_text()


def test_install_sh_wants_a_mode_in_one_line(tmp_path: Path) -> None:
    r = _install(tmp_path)
    assert r.returncode == 2 and not (tmp_path / "opt").exists()
    assert r.stderr.count("\n") == 1 and "--drone" in r.stderr and "--ground" in r.stderr


# -- a drone without the extras ----------------------------------------------------------------


def test_pyproject_core_is_the_drone_and_extras_hold_the_rest() -> None:
    """``pip install viscover`` (a drone) gets no extra's package; ``make test`` gets all."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    core = {re.split(r"[<>=!~\[ ]", d)[0].lower() for d in project["dependencies"]}
    assert core == {"numpy", "msgspec", "eclipse-zenoh", "pymavlink", "pyserial", "scipy",
                    "trimesh", "rtree", "libigl", "cryptography"}
    extras = project["optional-dependencies"]
    assert [d.split(">")[0] for d in extras["mocap"]] == ["motioncapture"]
    assert [d.split(">")[0] for d in extras["occlusion-fast"]] == ["embreex"]
    assert {d.split(">")[0] for d in extras["ground"]} == {"matplotlib", "foxglove-sdk", "mcap",
                                                           "rich"}
    assert "viscover[ground,mocap,occlusion-fast]" in extras["test"]


def test_drone_commands_run_without_the_extras_and_the_others_say_which() -> None:
    """With every extra's package unimportable: the drone's commands parse, ``viscover
    --help`` lists every command, and a command needing an extra says which in one line."""
    for cmd in ("agent", "fly", "preflight", "router", "status", "land", "observe"):
        r = _viscover(cmd, "--help", blocked=EXTRA_PACKAGES)
        assert r.returncode == 0 and r.stderr == "", (cmd, r.stderr)
    r = _viscover("--help", blocked=EXTRA_PACKAGES)
    assert r.returncode == 0, r.stderr
    assert "record       (needs viscover[ground]: not installed)" in r.stdout
    for argv, package in [(("record", "--scenario", str(CUBE), "--out", "x"), "foxglove"),
                          (("launch", str(CUBE)), "foxglove"), (("report", "x"), "mcap")]:
        r = _viscover(*argv, blocked=EXTRA_PACKAGES)
        assert (r.returncode, r.stderr) == (2, (
            f"viscover: error: viscover {argv[0]} needs the package {package}, which is not "
            "installed: install viscover[ground] (pip install 'viscover[ground]')\n"))
    r = _viscover("groundstation", "--source", "motioncapture", "--scenario", str(CUBE),
                  blocked=EXTRA_PACKAGES)
    assert (r.returncode, r.stderr) == (2, NO_MOCAP)


def test_occlusion_falls_back_without_embreex_and_says_so_once() -> None:
    """Without embreex the pure caster gives the same answers, logged once in one line."""
    code = (
        "import sys, logging\nsys.modules['embreex'] = None\n"
        "logging.basicConfig(format='%(message)s')\n"
        "import numpy as np, trimesh\n"
        "from agent.structure.occlusion import OcclusionCaster, embree_available\n"
        "assert not embree_available()\n"
        "box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))\n"
        "q = np.array([[0.5, 0, 0], [-0.5, 0, 0]]); u = np.array([[1.0, 0, 0], [-1.0, 0, 0]])\n"
        "for _ in range(2):\n"
        "    print(OcclusionCaster(box).unoccluded([3.0, 0, 0], q, u).tolist())\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       env=repo_env(), timeout=60, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines() == ["[True, False]", "[True, False]"]
    assert r.stderr == SLOW_CASTER + "\n"


def test_kinematic_agent_flies_a_mesh_mission_without_the_extras(tmp_path: Path) -> None:
    """The honest check of a drone-only install: a kinematic agent of a scenario with mesh
    occlusion runs against a router with every extra's package unimportable, publishes its
    state, and says in one line that it uses the slow ray caster."""
    proc, endpoint = start_router_process()
    try:
        r = _viscover("agent", "--id", "A", "--scenario", str(scenario_path("tower")),
                      "--connect", endpoint, "--state-dir", str(tmp_path / "A"),
                      "--rate-scale", "10", "--timeout", "3", blocked=EXTRA_PACKAGES,
                      timeout=120)
    finally:
        stop_router_process(proc)
    assert "Traceback" not in r.stderr and "ModuleNotFoundError" not in r.stderr, r.stderr
    assert r.returncode in (0, 3), r.stderr  # 3: not complete within --timeout (alone)
    assert [ln for ln in r.stderr.splitlines() if SLOW_CASTER in ln] != []
    assert sum(SLOW_CASTER in ln for ln in r.stderr.splitlines()) == 1
    assert os.listdir(tmp_path / "A")  # its journal
