"""The secured profile's files and plumbing: deploy/make-certs.py (make, add a drone, renew),
the shipped broker_config profiles, how every command and ``viscover launch`` pick their
identity, and the systemd units' sandboxing."""

from __future__ import annotations

import argparse
import importlib.util
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
import zenoh

from agent.cli import build_parser
from agent.commands import kit
from agent.commands.agent import agent_options
from agent.errors import UsageError
from agent.mission.launcher import Launcher, LaunchPlan
from agent.net.security import ENV_TLS_DIR, TeamDir, router_config
from tests.agent_helpers import thesis
from tests.conftest import ROOT, scenario_path


def get(cfg: zenoh.Config, path: str) -> Any:
    """The value at ``path`` of a Zenoh config (parsed JSON)."""
    return json.loads(cfg.get_json(path))


def make_certs() -> ModuleType:
    """deploy/make-certs.py as a module."""
    spec = importlib.util.spec_from_file_location("make_certs", ROOT / "deploy" / "make-certs.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def team(tmp_path_factory: pytest.TempPathFactory) -> TeamDir:
    """A team directory for A, B, C made by deploy/make-certs.py."""
    out = tmp_path_factory.mktemp("team") / "certs"
    assert make_certs().main(["--out", str(out), "--drones", "A,B,C"]) == 0
    return TeamDir(out.resolve())


def test_make_certs_makes_adds_and_renews(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                          ) -> None:
    mc = make_certs()
    out = tmp_path / "certs"
    mc.main(["--out", str(out), "--drones", "A,B", "--host", "ground.local"])
    team = TeamDir(out)
    private = [p for p in out.iterdir() if p.suffix in (".key", ".sign")]
    assert {p.name for p in private} >= {"ca.key", "drone-A.key", "drone-A.sign", "ground.key"}
    assert all(p.stat().st_mode & 0o077 == 0 for p in private)  # keys: owner only
    ca, a_sign, a_pem = (out / "ca.pem").read_bytes(), team.sign_key("A").read_bytes(), \
        team.cert("drone-A").read_bytes()
    mc.main(["--out", str(out), "--drones", "C"])  # add a drone: everything else is kept
    assert team.drones() == ["A", "B", "C"]
    assert (out / "ca.pem").read_bytes() == ca and team.sign_key("A").read_bytes() == a_sign
    mc.main(["--out", str(out), "--renew"])  # rotate: new leaves and keys, same CA
    assert (out / "ca.pem").read_bytes() == ca and team.cert("drone-A").read_bytes() != a_pem
    assert team.sign_key("A").read_bytes() != a_sign and team.drones() == ["A", "B", "C"]
    cfg = zenoh.Config.from_file(str(out / "router.json5"))
    names = [s["cert_common_names"] for s in get(cfg, "access_control/subjects")]
    assert ["drone-C"] in names
    mc.main(["--out", str(out), "--remove", "B"])  # B leaves the team
    assert team.drones() == ["A", "C"] and not team.sign_key("B").exists()
    names = [s["cert_common_names"] for s in get(zenoh.Config.from_file(
        str(out / "router.json5")), "access_control/subjects")]
    assert ["drone-B"] not in names and ["drone-A"] in names
    assert "drones A, B, C" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        mc.main(["--out", str(out), "--drones", "A/B"])


def strip_comments(text: str) -> str:
    """json5 file text without its ``//`` comment lines."""
    return "\n".join(line for line in text.splitlines() if not line.lstrip().startswith("//"))


def test_shipped_profiles_match_the_generator() -> None:
    etc = Path("/etc/viscover/certs")
    shipped = json.loads(strip_comments(
        (ROOT / "broker_config" / "router_secure.json5").read_text()))
    assert shipped == router_config(TeamDir(etc), ["tls/0.0.0.0:7447"], drones=["A", "B", "C"])
    client = zenoh.Config.from_file(str(ROOT / "broker_config" / "client_secure.json5"))
    assert get(client, "transport/link/tls") == {
        **get(client, "transport/link/tls"), "enable_mtls": True,
        "root_ca_certificate": str(etc / "ca.pem"),
        "connect_certificate": str(etc / "drone-A.pem")}
    for name in ("router.json5", "agent.json5", "router_b.json5"):  # open profiles kept
        assert (ROOT / "broker_config" / name).is_file()


def parse(*argv: str) -> argparse.Namespace:
    """``viscover agent|observe`` arguments parsed."""
    return build_parser(["agent", "observe"]).parse_args(list(argv))


def cert_of(cfg: zenoh.Config) -> str:
    """File name of the certificate a client config presents."""
    return Path(get(cfg, "transport/link/tls/connect_certificate")).name


def test_every_command_presents_its_own_identity(team: TeamDir,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    hexagon = str(scenario_path("hexagon_5_3"))
    ep = "tls/localhost:7447"
    opts = agent_options(parse("agent", "--id", "B", "--scenario", hexagon, "--connect", ep,
                               "--tls-dir", str(team.path)))
    assert cert_of(opts.zenoh) == "drone-B.pem" and opts.signing is not None
    assert opts.signing.me == "B" and sorted(opts.signing.team) == ["A", "B", "C"]
    assert opts.runtime_config(1.0).signing is opts.signing
    obs = parse("observe", "--scenario", hexagon, "--tls-dir", str(team.path))
    assert cert_of(kit.zenoh_config(obs, "observer")) == "observer.pem"
    # The ground station (and `viscover land`) pass no role: the ground certificate.
    assert cert_of(kit.zenoh_config(obs)) == "ground.pem"
    obs.identity = "drone-C"
    assert cert_of(kit.zenoh_config(obs, "observer")) == "drone-C.pem"
    # $VISCOVER_TLS_DIR instead of --tls-dir; a --zenoh file gets the TLS block inserted.
    monkeypatch.setenv(ENV_TLS_DIR, str(team.path))
    filed = parse("observe", "--scenario", hexagon, "--zenoh",
                  str(ROOT / "broker_config" / "client_secure.json5"))
    assert cert_of(kit.zenoh_config(filed, "observer")) == "observer.pem"
    open_opts = agent_options(parse("agent", "--id", "A", "--scenario", hexagon))
    assert open_opts.signing is not None  # from the environment
    monkeypatch.delenv(ENV_TLS_DIR)
    assert agent_options(parse("agent", "--id", "A", "--scenario", hexagon)).signing is None


def test_secured_profile_mistakes_are_one_line(team: TeamDir, tmp_path: Path) -> None:
    hexagon = str(scenario_path("hexagon_5_3"))
    cases = {
        "connects over TLS": ("--connect", "tcp/127.0.0.1:7447", "--tls-dir", str(team.path)),
        "not a directory": ("--tls-dir", str(tmp_path / "none")),
    }
    for what, extra in cases.items():
        with pytest.raises(UsageError, match=what):
            agent_options(parse("agent", "--id", "A", "--scenario", hexagon, *extra))
    partial = tmp_path / "partial"
    shutil.copytree(team.path, partial)
    (partial / "drone-A.sign").unlink()
    with pytest.raises(UsageError, match=r"drone-A\.sign missing"):
        agent_options(parse("agent", "--id", "A", "--scenario", hexagon, "--tls-dir",
                            str(partial)))


def test_launch_passes_the_profile_to_every_process(team: TeamDir, tmp_path: Path) -> None:
    plan = LaunchPlan(scenario_path=str(scenario_path("hexagon_5_3")),
                      scenario=thesis("hexagon_5_3"), mission="m", run_dir=tmp_path,
                      ids=("A",), tls_dir=str(team.path))
    launcher = Launcher(plan)
    launcher.endpoint = "tls/localhost:7447"
    cmd = launcher.agent_command("A")
    assert cmd[cmd.index("--tls-dir") + 1] == str(team.path)
    assert security_cert(launcher) == "observer.pem"
    assert Launcher(LaunchPlan(plan.scenario_path, plan.scenario, "m", tmp_path)).security is None


def security_cert(launcher: Launcher) -> str:
    """The certificate the launcher's own (observer) session presents."""
    assert launcher.security is not None
    return cert_of(launcher.security.client_config(launcher.endpoint))


UNITS = sorted((ROOT / "deploy" / "systemd").glob("*.service"))


@pytest.mark.parametrize("unit", UNITS, ids=lambda p: p.name)
def test_units_run_sandboxed_as_viscover(unit: Path, tmp_path: Path) -> None:
    """The sandboxing every unit declares, and (where systemd-analyze exists, as on the
    project's CI machine) its exposure level below 5."""
    text = unit.read_text()
    assert "User=viscover" in text and "NoNewPrivileges=yes" in text
    assert "/etc/viscover/viscover.env" in text
    for option in ("ProtectSystem=strict", "ProtectHome=yes", "PrivateTmp=yes",
                   "CapabilityBoundingSet=", "SystemCallFilter=", "RestrictAddressFamilies=",
                   "ProtectKernelTunables=yes", "RestrictNamespaces=yes"):
        assert any(line.startswith(option) for line in text.splitlines()), option
    tool = shutil.which("systemd-analyze")
    if tool is None or not sys.platform.startswith("linux"):
        return  # the declarations above are what the exposure level is computed from
    path = tmp_path / unit.name.replace("@.", "@A.")  # an instance of a template unit
    path.write_text(text)
    out = subprocess.run([tool, "security", "--offline=true", str(path)], capture_output=True,
                         text=True, timeout=30).stdout
    level = re.search(r"Overall exposure level for \S+: ([0-9.]+)", out)
    assert level is not None, out[-500:]
    assert float(level.group(1)) < 5.0
