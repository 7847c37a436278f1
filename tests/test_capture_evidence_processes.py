"""Captures as evidence across processes (issue 33): three agent processes inspect the wind
turbine on the secured profile (a TLS router, signed trades) while a hostile insider holding
drone C's certificate rewrites every state C publishes into one that claims every landmark
captured (its captured set all ones, and claims from made-up poses in front of each landmark
and of the uncapturable ones), keeping C's genuine claims (:class:`bench.chaos_captures.Forger`,
the campaign's ``false_capture`` attack). Before captures were evidence, the
team believed C's word and stopped with most landmarks never imaged, reporting more captured
than capturable. Now the peers refuse the claims (counted), the mission captures every
capturable landmark for real (the journals), no uncapturable landmark is reported captured,
and the observer counts the refusals."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from agent.config.parse import load_scenario
from agent.mission.observer import Observer
from agent.net.security import OBSERVER, TeamDir
from agent.net.security import client_config as secure_config
from agent.net.transport import ZenohTransport
from agent.protocol.captures import POSE, UNCAPTURABLE
from agent.world.structure import resolve_structure
from agent.world.tables import mission_tables
from bench.chaos_captures import Forger
from bench.inspection.recheck import journal_captures, recheck_records
from tests.conftest import scenario_path
from tests.test_agent_processes import spawn_agent, wait_all

PATH = scenario_path("inspect_wind_turbine")
M = "inspect_wind_turbine"  #: the mission: the scenario's name


@pytest.mark.slow
@pytest.mark.serial
def test_a_drone_claiming_every_landmark_captured_is_refused_and_the_mission_captures_all(
        team: TeamDir, secured_router: str, tmp_path: Path) -> None:
    sc = resolve_structure(load_scenario(PATH))
    table, _ = mission_tables(sc)
    capturable = set(np.asarray(sc.landmark_ids)[table.capturable].tolist())
    assert len(capturable) == 39 < len(sc.landmark_ids) == 41
    forger = Forger(team, secured_router, sc)
    obs_tp = ZenohTransport(secure_config(team, [secured_router], OBSERVER), None, "observer")
    obs = Observer(obs_tp, M, [a.id for a in sc.agents], list(sc.landmark_ids),
                   initial=sc.initial_sets())
    try:
        outs = wait_all([spawn_agent(a.id, PATH, secured_router, tmp_path, "--tls-dir",
                                     str(team.path), timeout=120.0)
                         for a in sc.agents], timeout=180)
        assert obs.done.wait(20.0)
        rep = obs.snapshot()
    finally:
        obs.close()
        obs_tp.close()
        forger.close()
    assert forger.forged > 5  # C's states were rewritten all along
    lines = {a.id: json.loads(next(x for x in out.splitlines() if x.startswith("{")))
             for a, out in zip(sc.agents, outs, strict=True)}
    for aid, line in lines.items():  # every view: exactly the capturable set, nothing more
        assert line["captured"] == line["capturable"] == 39, (aid, line)
    for aid in ("A", "B"):  # C's peers refused its lies, and counted them by reason
        refused = lines[aid]["refused_claims"]
        assert refused.get(POSE, 0) > 0 and refused.get(UNCAPTURABLE, 0) > 0, lines[aid]
    # the landmarks were captured for real: the journals hold every capturable one, each
    # capture holds when re-checked from its journaled pose, and nothing uncapturable
    recs = journal_captures(tmp_path, [a.id for a in sc.agents])
    assert {lid for r in recs for lid in r.ids} == capturable
    assert recheck_records(sc, recs) == 0
    # the observer: complete, 39 captured, the refusals reported; its only violations name the
    # insider (C's states come from two processes: the genuine and the rewritten stream)
    assert all(v.startswith("agent C: ") for v in rep.violations), rep.violations
    assert rep.complete
    assert rep.inspection is not None and rep.inspection["captured"] == 39
    assert rep.agents["A"]["refused_claims"] > 0 and rep.agents["B"]["refused_claims"] > 0
