"""The coverage-move decisions are decentralised: pure functions of their arguments.

Each decision function takes only the deciding agent's own state, its peers' published
messages and the mission constants. We check that (1) the modules import nothing but numpy
and agent.core, (2) the functions reach no mutable global state (only modules, functions,
classes and immutable constants), (3) they neither mutate their arguments nor depend on
anything else: the same arguments give the same answer, whatever else exists.
"""

from __future__ import annotations

import ast
import copy
import inspect
import types
from pathlib import Path

import numpy as np

from agent.core import coverage_moves, viewpoints
from agent.core.coverage_moves import (
    OwnState,
    PeerMessage,
    cluster_partition,
    group_proposal,
    pair_proposal,
    relocation_goal,
)
from agent.core.landmarks import box_faces
from agent.core.viewpoints import Environment

DECISIONS = (relocation_goal, pair_proposal, group_proposal, cluster_partition)
ROOT = Path(__file__).resolve().parents[1]


def test_modules_import_only_numpy_and_agent_core() -> None:
    for mod in (viewpoints, coverage_moves):
        tree = ast.parse(Path(mod.__file__ or "").read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            else:
                continue
            for name in names:
                assert name in ("numpy", "__future__", "dataclasses") or name.startswith(
                    ("numpy.", "agent.core.")), f"{mod.__name__} imports {name}"


def _globals_reached(fn: types.FunctionType, seen: set[str]) -> dict[str, object]:
    """Global names a function reaches, following functions of the same package."""
    out: dict[str, object] = {}
    cv = inspect.getclosurevars(fn)
    assert not cv.nonlocals, f"{fn.__name__} closes over {list(cv.nonlocals)}"
    for name, value in cv.globals.items():
        out[name] = value
        if (isinstance(value, types.FunctionType) and value.__module__.startswith("agent.core")
                and value.__qualname__ not in seen):
            seen.add(value.__qualname__)
            out.update(_globals_reached(value, seen))
    return out


def test_decisions_reach_no_mutable_global_state() -> None:
    immutable = (int, float, str, bytes, bool, tuple, frozenset, type(None))
    for fn in DECISIONS:
        assert isinstance(fn, types.FunctionType)
        for name, value in _globals_reached(fn, set()).items():
            ok = (inspect.ismodule(value) or inspect.isclass(value) or callable(value)
                  or isinstance(value, immutable))
            assert ok, f"{fn.__name__} reaches mutable global {name} = {value!r}"


def _world(extra_agents: int) -> tuple[OwnState, PeerMessage, np.ndarray, Environment]:
    """Two agents around a box; ``extra_agents`` others far away that are *not* passed."""
    q, u = box_faces([0.0, 0.0, 1.5], [4.0, 3.0, 3.0], ["+x", "-x", "+y", "-y"], (2, 2))
    ids = np.arange(q.shape[0], dtype=np.int64)
    a = ids[ids % 2 == 0]
    b = ids[ids % 2 == 1]
    env = Environment(np.array([-8.0, -8.0, 0.3]), np.array([8.0, 8.0, 6.0]),
                      np.array([[[-2.0, -1.5, 0.0], [2.0, 1.5, 3.0]]]), 0.3, 1.0)
    own = OwnState("A", np.array([5.0, 0.0, 1.5]), np.array([-1.0, 0.0, 0.0]), a, q[a], u[a],
                   0.5)
    peer = PeerMessage("B", np.array([0.0, 5.0, 1.5]), np.array([0.0, -1.0, 0.0]), b, q[b],
                       u[b], 0.4, True)
    rng = np.random.default_rng(extra_agents)
    _unpassed = rng.uniform(-8, 8, size=(extra_agents, 3))  # exists, but is not an argument
    others = np.array([[-6.0, -6.0, 2.0]])
    return own, peer, others, env


def test_decisions_depend_only_on_their_arguments_and_do_not_mutate_them() -> None:
    own, peer, others, env = _world(0)
    args = (own, peer, others, env)
    before = copy.deepcopy(args)
    p1 = pair_proposal(own, peer, others, env, 2.0)
    g1 = relocation_goal(own, others, env, 2.0)
    own2, peer2, others2, env2 = _world(5)  # another world, same arguments
    p2 = pair_proposal(own2, peer2, others2, env2, 2.0)
    g2 = relocation_goal(own2, others2, env2, 2.0)
    for x, y in zip(args, before, strict=True):
        for f in ("p", "v", "ids", "q", "u"):
            if hasattr(x, f):
                assert np.array_equal(getattr(x, f), getattr(y, f))
    assert np.array_equal(others, before[2])
    assert p1 is not None and p2 is not None
    assert np.array_equal(p1.a_ids, p2.a_ids) and np.array_equal(p1.goals[1].p, p2.goals[1].p)
    assert p1.gain > 0 and np.array_equal(np.sort(np.concatenate([p1.a_ids, p1.b_ids])),
                                          np.sort(np.concatenate([own.ids, peer.ids])))
    assert (g1 is None) == (g2 is None)
    if g1 is not None and g2 is not None:
        assert np.array_equal(g1.p, g2.p)


def test_busy_peer_is_not_asked() -> None:
    own, peer, others, env = _world(0)
    busy = PeerMessage(peer.id, peer.p, peer.v, peer.ids, peer.q, peer.u, peer.vision, False)
    assert pair_proposal(own, busy, others, env, 2.0) is None


def test_three_way_proposal_covers_the_union_and_names_every_member() -> None:
    own, peer, others, env = _world(0)
    half = peer.ids.size // 2
    p2 = PeerMessage("B", peer.p, peer.v, peer.ids[:half], peer.q[:half], peer.u[:half], 0.2,
                     True)
    p3 = PeerMessage("C", np.array([-5.0, 0.0, 1.5]), np.array([1.0, 0.0, 0.0]),
                     peer.ids[half:], peer.q[half:], peer.u[half:], 0.2, True)
    prop = group_proposal(own, (p2, p3), others, env, 2.0)
    assert prop is not None and prop.members == ("A", "B", "C")
    union = np.sort(np.concatenate([own.ids, peer.ids]))
    assert np.array_equal(np.sort(np.concatenate(prop.sets)), union)
    for g in prop.goals:
        assert feasible_point(g.p, env)
    assert prop.gain > 0


def feasible_point(p: np.ndarray, env: Environment) -> bool:
    """Whether one position is allowed by the environment (helper of the test above)."""
    from agent.core.viewpoints import feasible

    return bool(feasible(p[None, :], env)[0])
