"""Captures as evidence (issue 33): a peer's capture claim is merged only when its camera pose
lies on the trajectory the claimer published (and on the ground station's mocap of it) and
the inspection's own capture test holds from it; an uncapturable landmark is never accepted;
a state without evidence is refused and counted. And a flown drone's capture counts only once
its camera said it took the image (CAMERA_IMAGE_CAPTURED / CAMERA_FEEDBACK), stepped into the
core as an ImageTaken event: no confirmation, no capture."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from agent.config.parse import load_scenario
from agent.config.scenario import Scenario
from agent.mission.status import summary_line
from agent.mission.watch import MissionView
from agent.protocol.captures import (
    BRACKET,
    MALFORMED,
    NEWEST,
    NO_EVIDENCE,
    NOT_CAPTURED,
    OLDER,
    POSE,
    UNCAPTURABLE,
    OwnClaims,
    Tracks,
    agreed_bits,
    pose_agrees,
    split_claims,
)
from agent.protocol.records import CaptureRec
from agent.runtime.core.agent_core import AgentCore
from agent.runtime.core.events import (
    Answer,
    Ask,
    AskHedged,
    Command,
    Compute,
    Effect,
    Fix,
    ImageTaken,
    Persist,
    Publish,
    Start,
    Tick,
    Trigger,
)
from agent.runtime.core.shared import AgentConfig, vec3
from agent.runtime.moves.inspecting import Inspecting
from agent.runtime.moves.shots import Captures
from agent.wire.codec import Codec
from agent.wire.ground import MOCAP_CODEC, MocapPose
from agent.wire.peer import (
    MAX_CAPTURE_CLAIMS,
    AgentState,
    CaptureClaim,
    Counters,
    Publication,
    pack,
    pack_bits,
)
from agent.world.inputs import World
from agent.world.prepare import prepare_world
from agent.world.structure import resolve_structure
from tests.conftest import scenario_path

PUB: Codec[Publication] = Codec(Publication)


@pytest.fixture(scope="module")
def turbine() -> tuple[Scenario, World]:
    """The wind-turbine inspection (two uncapturable landmarks) and its prepared world."""
    sc = resolve_structure(load_scenario(scenario_path("inspect_wind_turbine")))
    return sc, prepare_world(sc)


@pytest.fixture()
def ins(turbine: tuple[Scenario, World]) -> Iterator[Inspecting]:
    """Drone A's inspection part (a core built, never stepped)."""
    sc, world = turbine
    core = AgentCore("A", sc, [], AgentConfig(mission="ev"), world)
    assert core.planning.inspecting is not None
    yield core.planning.inspecting


def viewpoint(ins: Inspecting) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A viewpoint of the capture table (p [m; world ENU], unit v) and the landmarks (m,) a
    capture from it takes."""
    for j in range(ins.table.P.shape[0]):
        p, v = ins.table.P[j], ins.table.V[j]
        got = ins.captures_at(p, v)
        if got.sum() >= 2:
            return p, v, got
    raise AssertionError("no viewpoint captures two landmarks")


def state(sender: str, p: np.ndarray, v: np.ndarray, t: float,
          claims: list[CaptureClaim] | None, captured: bytes = b"", seq: int = 1
          ) -> AgentState:
    """A peer's state at its mission time t [s], pose (p, v), with ``claims``."""
    return AgentState(
        sender=sender, incarnation=1, seq=seq, t=t, p=vec3(p), v=vec3(v), phase="optimising",
        owned=pack({}), held=pack({}), vision=0.0,
        counters=Counters(), partners=[], pending=[], trades_with={}, captured=captured,
        claims=claims)


def test_a_claim_from_the_pose_the_claimer_published_is_merged(ins: Inspecting) -> None:
    p, v, got = viewpoint(ins)
    ids = ins.ids[got].tolist()
    st = state("B", p, v, 10.0, split_claims(10.0, p, v, ids))
    ins.on_peer_state(st)
    assert (ins.cap == got).all() and ins.judge.accepted == 1
    assert ins.judge.refused_total == 0
    # sent again (every state carries it): not judged again
    ins.on_peer_state(state("B", p, v, 10.2, split_claims(10.0, p, v, ids), seq=2))
    assert (ins.cap == got).all() and ins.judge.accepted == 1


def test_a_claim_from_a_made_up_pose_is_refused(ins: Inspecting) -> None:
    p, v, got = viewpoint(ins)
    elsewhere = p + np.array([6.0, 0.0, 0.0])
    # B published itself 6 m away around the claimed time, then claims from the viewpoint
    for t in (9.5, 10.0, 10.5):
        ins.judge.tracks.add("B", t, elsewhere, v)
    st = state("B", elsewhere, v, 10.5, split_claims(10.0, p, v, ins.ids[got].tolist()))
    assert not ins.judge.judge(st, ins.cap, 10.5).any()
    assert ins.judge.refused == {POSE: 1}
    # a direction off by more than the tolerance is refused too
    ins.judge.tracks.add("C", 10.0, p, -v)
    st = state("C", p, -v, 10.0, split_claims(10.0, p, v, ins.ids[got].tolist()))
    assert not ins.judge.judge(st, ins.cap, 10.0).any()
    assert ins.judge.refused[POSE] == 2


def test_a_claim_between_samples_far_apart_is_judged_by_what_the_drone_could_reach(
        ins: Inspecting) -> None:
    """Samples 2 s apart (a drone heard through its states, or lost samples): a capture off
    their chord but within reach of both at 2·ṗ_lim is accepted; one beyond reach is not."""
    p, v, got = viewpoint(ins)
    ids = ins.ids[got].tolist()
    reach = 2.0 * ins.sc.params.p_lim  # m/s
    side = np.cross(v, [0.0, 0.0, 1.0])
    side = side / np.linalg.norm(side)
    for aid, off in (("B", 0.8 * reach), ("C", 1.6 * reach)):  # off the chord, 1 s from each
        a, b = p + off * side - v, p + off * side + v  # the chord runs 'off' metres aside
        ins.judge.tracks.add(aid, 9.0, a, v)
        ins.judge.tracks.add(aid, 11.0, b, v)
        st = state(aid, b, v, 11.0, split_claims(10.0, p, v, ids))
        ins.judge.judge(st, ins.cap, 11.0)
    assert ins.judge.accepted == 1 and ins.judge.refused == {POSE: 1}


def test_a_claim_on_the_published_pose_but_the_mocap_elsewhere_is_refused(
        ins: Inspecting) -> None:
    p, v, got = viewpoint(ins)
    for t in (9.9, 10.0, 10.1):  # the ground station saw B 3 m below
        below = [float(x) for x in p - [0.0, 0.0, 3.0]]
        mocap = MocapPose(drone="B", seq=int(t * 10), t=t, p=below, q=[1.0, 0.0, 0.0, 0.0],
                          v=[0.0, 0.0, 0.0])
        ins.judge.heard_mocap("viscover/ev/mocap/B", MOCAP_CODEC.encode(mocap), t)
    st = state("B", p, v, 10.0, split_claims(10.0, p, v, ins.ids[got].tolist()))
    assert not ins.judge.judge(st, ins.cap, 10.0).any()
    assert ins.judge.refused == {POSE: 1}


def test_a_claim_the_capture_test_fails_for_is_refused(ins: Inspecting) -> None:
    p, v, got = viewpoint(ins)
    behind = np.flatnonzero(~got & ins.table.capturable)[:1]  # not imaged from p
    ids = [*ins.ids[got].tolist(), *ins.ids[behind].tolist()]
    st = state("B", p, v, 10.0, split_claims(10.0, p, v, ids))
    assert not ins.judge.judge(st, ins.cap, 10.0).any()  # the whole claim is refused
    assert ins.judge.refused == {NOT_CAPTURED: 1}


def test_an_uncapturable_landmark_is_never_accepted(ins: Inspecting) -> None:
    p, v, got = viewpoint(ins)
    bad = np.flatnonzero(~ins.table.capturable)
    assert bad.size == 2  # the mast's top, inside the nacelle
    for k, row in enumerate(bad):  # even from the best pose there is, alone or with others
        ids = [int(ins.ids[row])] + (ins.ids[got].tolist() if k else [])
        st = state("B", p, v, 10.0 + k, split_claims(10.0 + k, p, v, ids))
        assert not ins.judge.judge(st, ins.cap, 10.0 + k).any()
    assert ins.judge.refused == {UNCAPTURABLE: 2}
    assert not ins.cap[bad].any()


def test_a_state_without_evidence_is_refused_counted_and_not_merged(ins: Inspecting) -> None:
    p, v, _ = viewpoint(ins)
    every = pack_bits(np.ones(ins.ids.size, dtype=np.bool_))
    ins.on_peer_state(state("C", p, v, 12.0, None, captured=every))  # a build before claims
    ins.on_peer_state(state("C", p, v, 12.2, None, captured=every, seq=2))  # counted once
    assert not ins.cap.any()
    assert ins.judge.refused == {NO_EVIDENCE: ins.ids.size}
    # a state of this build naming everything captured but proving nothing: nothing merged
    ins.on_peer_state(state("B", p, v, 12.0, [], captured=every))
    assert not ins.cap.any()


def test_malformed_and_unheard_claims(ins: Inspecting) -> None:
    p, v, got = viewpoint(ins)
    ids = ins.ids[got].tolist()
    good = split_claims(10.0, p, v, ids)[0]
    twice = CaptureClaim(good.version, good.t, good.p, good.v, good.ids + good.ids[:8])
    unknown = split_claims(10.0, p, v, [10**9])[0]
    future = CaptureClaim(99, good.t, good.p, good.v, good.ids)
    st = state("B", p, v, 10.0, [twice, unknown, future])
    assert not ins.judge.judge(st, ins.cap, 10.0).any()
    assert ins.judge.refused == {MALFORMED: 3}
    # a claim whose time no pose of the claimer is heard near: neither merged nor refused
    st = state("B", p, v, 10.0, split_claims(500.0, p, v, ids))
    assert not ins.judge.judge(st, ins.cap, 10.0).any()
    assert ins.judge.refused == {MALFORMED: 3} and ins.judge.accepted == 0


def test_claims_travel_bounded_and_every_one_is_sent_again() -> None:
    own = OwnClaims()
    for k in range(40):
        own.add(float(k), np.zeros(3), np.array([1.0, 0.0, 0.0]), [k])
    sent: set[float] = set()
    for _ in range(6):
        w = own.window()
        assert len(w) == NEWEST + OLDER <= MAX_CAPTURE_CLAIMS
        sent |= {c.t for c in w}
    assert sent == {float(k) for k in range(40)}
    st = state("B", np.zeros(3), np.array([1.0, 0.0, 0.0]), 1.0, own.window())
    back = PUB.decode(PUB.encode(st))
    assert isinstance(back, AgentState) and back.claims == st.claims
    too_many = state("B", np.zeros(3), np.array([1.0, 0.0, 0.0]), 1.0, own.claims)
    assert PUB.decode(PUB.encode(too_many)) is None  # bounded at decoding
    old = state("B", np.zeros(3), np.array([1.0, 0.0, 0.0]), 1.0, None)
    back = PUB.decode(PUB.encode(old))
    assert isinstance(back, AgentState) and back.claims is None  # older builds: no field


def test_pose_agrees_with_a_polyline_and_observers_need_a_majority() -> None:
    track = np.array([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0], [2.0, 0.0, 0.0, 0.0, 1.0, 0.0]])
    x = np.array([1.0, 0.3, 0.0])
    assert pose_agrees(track, x, np.array([0.7, 0.7, 0.0]) / np.hypot(0.7, 0.7), 0.5, 0.35)
    assert not pose_agrees(track, x + np.array([0.0, 0.4, 0.0]), None, 0.5, 0.35)
    assert not pose_agrees(track, x, np.array([-1.0, 0.0, 0.0]), 0.5, 0.35)
    a = pack_bits(np.array([True, True, False]))
    b = pack_bits(np.array([True, False, False]))
    c = pack_bits(np.array([True, True, True]))  # one drone's word alone counts nothing
    assert agreed_bits([a, b, c], 3).tolist() == [True, True, False]


# -- a flown drone: the camera's word ------------------------------------------------------


def test_a_confirming_cameras_capture_counts_only_when_the_image_was_taken() -> None:
    ids = np.array([5, 6, 7, 8], dtype=np.int64)
    recs: list[CaptureRec] = []
    fired: list[list[int]] = []
    caps = Captures(ids, [], recs.append, fired.append)
    caps.camera = True
    p, v = np.array([1.0, 2.0, 3.0]), np.array([1.0, 0.0, 0.0])
    assert caps.took(np.array([0, 1]), 4.0, p, v, [0.9, 0.8]) == []
    assert fired == [[5, 6]] and recs == [] and not caps.cap.any()
    assert caps.done[:2].all()  # not asked again meanwhile
    caps.on_image(ImageTaken(4.5, (5, 6), False, "no captured message after 3 attempts"))
    assert recs == [] and not caps.cap.any() and not caps.done.any()
    caps.took(np.array([0, 1]), 6.0, p, v, [0.9, 0.8])
    caps.expire(40.0)  # never answered: not taken
    assert not caps.done.any() and recs == []
    caps.took(np.array([2]), 41.0, p, v, [0.7])
    caps.on_image(ImageTaken(41.2, (7,), True))
    assert [r.ids for r in recs] == [[7]] and recs[0].t == 41.0 and caps.cap.tolist() == [
        False, False, True, False]
    assert [c.t for c in caps.own.claims] == [41.0]


def _drive(core: AgentCore, effects: list[Effect], fix: Fix, now: float
           ) -> tuple[list[Effect], Fix]:
    """Carry a tick's waits out by hand (kinematic vehicle, no peers): every effect."""
    out = list(effects)
    while out and isinstance(out[-1], Command | Compute | Ask | AskHedged):
        w = out[-1]
        if isinstance(w, Command):
            v = fix.v + np.cross(w.omega, fix.v) * w.dt
            fix = Fix(fix.p + w.p_dot * w.dt, v / np.linalg.norm(v), fix.t + w.dt)
            got = core.step(Answer(fix, now))
        elif isinstance(w, Compute):
            got = core.step(Answer(w.fn(), now))
        else:
            got = core.step(Answer(None, now))
        out += got
    return out, fix


def test_a_flown_core_journals_a_capture_only_after_the_cameras_word(
        turbine: tuple[Scenario, World]) -> None:
    sc, world = turbine
    core = AgentCore("A", sc, [], AgentConfig(mission="ev", require_all=False), world)
    spec = next(a for a in sc.agents if a.id == "A")
    fix = Fix(np.asarray(spec.p0, float), np.asarray(spec.v0, float), 0.0)
    core.step(Start(0.0, fix, camera=True))
    trigger: Trigger | None = None
    now = 0.0
    while trigger is None and now < 120.0:
        now = round(now + 0.1, 6)
        out, fix = _drive(core, core.step(Tick(now, fix)), fix, now)
        records = [r for e in out if isinstance(e, Persist) for r in e.records]
        assert not any(isinstance(r, CaptureRec) for r in records)  # nothing before the word
        trigger = next((e for e in out if isinstance(e, Trigger)), None)
    assert trigger is not None, "no image asked for in 120 s"
    for _ in range(30):  # no CAMERA_IMAGE_CAPTURED: not captured, whatever the ticks
        now = round(now + 0.1, 6)
        out, fix = _drive(core, core.step(Tick(now, fix)), fix, now)
        assert not any(isinstance(r, CaptureRec) for e in out if isinstance(e, Persist)
                       for r in e.records)
    assert core.machine.captured == []
    ins = core.planning.inspecting
    assert ins is not None and not ins.cap[np.isin(ins.ids, trigger.ids)].any()
    out = core.step(ImageTaken(now, trigger.ids, True))  # the camera took it
    recs = [r for e in out if isinstance(e, Persist) for r in e.records]
    assert [r.ids for r in recs if isinstance(r, CaptureRec)] == [list(trigger.ids)]
    assert core.machine.captured == list(trigger.ids)
    now = round(now + 0.1, 6)
    out, fix = _drive(core, core.step(Tick(now, fix)), fix, now)
    states = [PUB.decode(e.payload) for e in out if isinstance(e, Publish) and "/state/" in e.key]
    assert states and isinstance(st := states[-1], AgentState)
    assert st.claims is not None and {int(i) for c in st.claims
                                      for i in np.frombuffer(c.ids, "<i8")} >= set(trigger.ids)



def test_status_says_how_many_capture_claims_were_refused() -> None:
    view = MissionView(mission="ev", rows=[], coverage=0.0, seen=39, not_seen=0, unowned=0,
                       elapsed_s=1.0, mission_t=12.0, complete=False, violations=[],
                       rejected=0, captured=14, refused_claims=27)
    assert "captured 14/39 landmarks, capture claims refused 27;" in summary_line(view)


def test_a_track_brackets_the_claimed_time_and_stays_bounded() -> None:
    tracks = Tracks()
    x, v = np.array([1.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])
    tracks.add("B", 5.0, x, v)
    assert tracks.around("B", 5.5, 2.0) is None  # nothing heard after 5.5: not judged
    assert tracks.around("B", 4.0, 2.0) is None  # nor before 4.0 (it had not listened)
    for k in range(200):  # a forger's track: hundreds of samples at the same two times
        tracks.add("B", 6.0 if k % 2 else 7.0, x * k, v)
    got = tracks.around("B", 6.0, 2.0)
    assert got is not None and 0 < got.shape[0] <= 2 * BRACKET
    assert tracks.around("C", 6.0, 2.0) is None


def test_a_restarted_drone_claims_its_journaled_captures_again() -> None:
    recs = [CaptureRec(ids=[6], t=3.0, p=(1.0, 2.0, 3.0), v=(0.0, 1.0, 0.0)),
            CaptureRec(ids=[5, 8], t=4.0, p=(2.0, 2.0, 3.0), v=(0.0, 1.0, 0.0))]
    caps = Captures(np.array([5, 6, 7, 8], dtype=np.int64), recs, print, print)
    assert caps.cap.tolist() == [True, True, False, True]
    assert [(c.t, c.p) for c in caps.own.window()] == [(3.0, (1.0, 2.0, 3.0)),
                                                       (4.0, (2.0, 2.0, 3.0))]


def test_a_claim_unheard_around_its_time_is_judged_on_what_the_claimer_could_reach(
        ins: Inspecting) -> None:
    """No pose of B was heard around its claim (lost, or before this drone listened): merged
    when the claimed pose is within reach, at the planner's speed (with the margin), of B's
    start and of its first pose heard after the claim; left undecided (not merged, not
    refused) when B could not have been there yet."""
    p, v, got = viewpoint(ins)
    ids = ins.ids[got].tolist()
    start = next(a.p0 for a in ins.sc.agents if a.id == "B")
    reach = float(np.linalg.norm(p - np.asarray(start)))
    speed = ins.judge.speed
    too_soon = max(0.0, (reach - 1.0) / speed)  # B could not have flown that far yet
    st = state("B", p, v, too_soon + 30.0, split_claims(too_soon, p, v, ids))
    assert not ins.judge.judge(st, ins.cap, 40.0).any()
    assert ins.judge.accepted == 0 and ins.judge.refused_total == 0
    later = reach / speed + 1.0
    st = state("B", p, v, later + 30.0, split_claims(later, p, v, ids), seq=2)
    assert (ins.judge.judge(st, ins.cap, 80.0) == got).all()
    assert ins.judge.accepted == 1 and ins.judge.refused_total == 0
