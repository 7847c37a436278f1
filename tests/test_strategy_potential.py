"""The "potential" strategy's choice after a NoTrade on its own (no simulator, no agents):
:func:`agent.strategy.potential.resplit_after_no_trade` offers a pair re-split when one beats
the pair's visions, else a 3-member one with the next converged peer that helps, lazily, and
every proposal partitions exactly the members' landmarks."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from agent.core.coverage_moves import GroupProposal, OwnState, PeerMessage
from agent.core.landmarks import box_faces
from agent.core.viewpoints import Environment
from agent.core.vision import per_landmark
from agent.strategy.potential import resplit_after_no_trade

D_OPT = 2.0
ENV = Environment(np.array([-8.0, -8.0, 0.3]), np.array([8.0, 8.0, 7.0]),
                  np.array([[[-2.0, -1.5, 0.0], [2.0, 1.5, 3.0]]]), 0.3, 1.0)
FACES = ("+x", "-x", "+y", "-y")


def _faces() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every landmark of the four side faces: ids (face k: 100 k ...), q, u."""
    parts = [box_faces([0.0, 0.0, 1.5], [4.0, 3.0, 3.0], [f], (2, 2)) for f in FACES]
    ids = np.concatenate([np.arange(100 * (k + 1), 100 * (k + 1) + x[0].shape[0])
                          for k, x in enumerate(parts)]).astype(np.int64)
    return ids, np.vstack([x[0] for x in parts]), np.vstack([x[1] for x in parts])


ALL_IDS, ALL_Q, ALL_U = _faces()


def _own_ids(aid: str, p: np.ndarray, v: np.ndarray, ids: np.ndarray) -> OwnState:
    rows = np.searchsorted(ALL_IDS, np.sort(ids))
    q, u = ALL_Q[rows], ALL_U[rows]
    vv = np.asarray(v, dtype=np.float64) / np.linalg.norm(v)
    pp = np.asarray(p, dtype=np.float64)
    return OwnState(aid, pp, vv, ALL_IDS[rows], q, u,
                    float(per_landmark(pp, vv, q, u, D_OPT).sum()))


def _own(aid: str, p: list[float], v: list[float], faces: list[str]) -> OwnState:
    ids = np.concatenate([ALL_IDS[(ALL_IDS // 100) == FACES.index(f) + 1] for f in faces])
    return _own_ids(aid, np.asarray(p, dtype=np.float64), np.asarray(v, dtype=np.float64), ids)


def _msg(o: OwnState) -> PeerMessage:
    return PeerMessage(o.id, o.p, o.v, o.ids, o.q, o.u, o.vision, True)


def _no_others(_ids: tuple[str, ...]) -> np.ndarray:
    return np.zeros((0, 3))


def _partitions(prop: GroupProposal, members: list[OwnState]) -> None:
    union = np.sort(np.concatenate([m.ids for m in members]))
    got = np.sort(np.concatenate(prop.sets))
    assert np.array_equal(got, union)  # each landmark to exactly one member
    assert prop.members == tuple(m.id for m in members)
    assert all(np.array_equal(a, m.ids) for a, m in zip(prop.sets_before, members, strict=True))
    assert prop.gain > 0.0


def _unused() -> Iterator[PeerMessage]:
    raise AssertionError("a third was looked at although the pair re-split helps")
    yield  # pragma: no cover - makes this a generator


def test_a_pair_that_sees_its_faces_badly_gets_a_pair_resplit_and_no_third_is_asked() -> None:
    """A owns the -x face but looks at +x; B the other way round: swapping gains."""
    a = _own("A", [4.0, 0.0, 1.5], [-1.0, 0.0, 0.0], ["-x"])
    b = _own("B", [-4.0, 0.0, 1.5], [1.0, 0.0, 0.0], ["+x"])
    prop = resplit_after_no_trade(a, _msg(b), _unused(), _no_others, ENV, D_OPT)
    assert prop is not None and len(prop.members) == 2
    _partitions(prop, [a, b])


def test_an_optimal_pair_asks_the_next_peer_for_a_three_member_resplit() -> None:
    """A and B re-split until no pair re-split helps them any more; C holds the +y and -y
    faces from a pose that sees neither: then the triple with C helps, and only if triples
    are tried."""
    a = _own("A", [4.0, 0.0, 1.5], [-1.0, 0.0, 0.0], ["+x"])
    b = _own("B", [-4.0, 0.0, 1.5], [1.0, 0.0, 0.0], ["-x"])
    for _ in range(10):  # pair re-splits until a fixed point
        prop = resplit_after_no_trade(a, _msg(b), [], _no_others, ENV, D_OPT)
        if prop is None:
            break
        a = _own_ids("A", prop.goals[0].p, prop.goals[0].v, prop.sets[0])
        b = _own_ids("B", prop.goals[1].p, prop.goals[1].v, prop.sets[1])
    assert prop is None
    c = _own("C", [0.0, 0.0, 6.5], [0.0, 0.0, 1.0], ["+y", "-y"])
    assert resplit_after_no_trade(a, _msg(b), [_msg(c)], _no_others, ENV, D_OPT,
                                  triples=False) is None
    prop = resplit_after_no_trade(a, _msg(b), [_msg(c)], _no_others, ENV, D_OPT)
    assert prop is not None and len(prop.members) == 3
    _partitions(prop, [a, b, c])


def test_a_peer_still_optimising_gets_no_offer() -> None:
    a = _own("A", [4.0, 0.0, 1.5], [-1.0, 0.0, 0.0], ["-x"])
    b = _own("B", [-4.0, 0.0, 1.5], [1.0, 0.0, 0.0], ["+x"])
    moving = PeerMessage(b.id, b.p, b.v, b.ids, b.q, b.u, b.vision, False)
    assert resplit_after_no_trade(a, moving, [], _no_others, ENV, D_OPT) is None
