"""Trading of landmarks (thesis section 4.5, Algorithm 7) and the partner list."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from agent.core.trading import PartnerList, TradeOutcome, trade_landmarks
from tests.reference import Array, f_exp, random_unit, vis_naive, vis_one


def random_agents(rng: np.random.Generator) -> tuple[float, Array, Array, Array, Array, Array,
                                                     Array, Array, Array]:
    d_opt = float(rng.uniform(1.0, 4.0))
    ma, mb = int(rng.integers(0, 12)), int(rng.integers(0, 12))
    pa, pb = rng.uniform(-4, 4, 3), rng.uniform(-4, 4, 3)
    va, vb = random_unit(rng), random_unit(rng)
    qa, qb = rng.uniform(-3, 3, (ma, 3)), rng.uniform(-3, 3, (mb, 3))
    ua = random_unit(rng, ma) if ma else np.zeros((0, 3))
    ub = random_unit(rng, mb) if mb else np.zeros((0, 3))
    return d_opt, pa, va, qa, ua, pb, vb, qb, ub


def _row_order(x: Array) -> NDArray[np.intp]:
    """The permutation sorting the rows of ``x`` lexicographically (first column first)."""
    return np.lexsort(x.T[::-1])


def apply(outcome: TradeOutcome, qa: Array, ua: Array, qb: Array, ub: Array
          ) -> tuple[Array, Array, Array, Array]:
    """Q*_A = (Q_A minus what goes to B) ∪ (what comes from B); likewise Q*_B."""
    qa2 = np.vstack([qa[~outcome.a_to_b], qb[outcome.b_to_a]])
    ua2 = np.vstack([ua[~outcome.a_to_b], ub[outcome.b_to_a]])
    qb2 = np.vstack([qb[~outcome.b_to_a], qa[outcome.a_to_b]])
    ub2 = np.vstack([ub[~outcome.b_to_a], ua[outcome.a_to_b]])
    return qa2, ua2, qb2, ub2


def test_trade_increases_sum_and_preserves_partition() -> None:
    rng = np.random.default_rng(77)
    n_success = n_fail = 0
    for _ in range(800):
        d_opt, pa, va, qa, ua, pb, vb, qb, ub = random_agents(rng)
        f = lambda r, d=d_opt: f_exp(r, d)  # noqa: E731
        before = vis_naive(pa, va, qa, ua, f) + vis_naive(pb, vb, qb, ub, f)
        out = trade_landmarks(pa, va, qa, ua, pb, vb, qb, ub, d_opt)
        assert out.a_to_b.shape == (len(qa),) and out.b_to_a.shape == (len(qb),)
        qa2, ua2, qb2, ub2 = apply(out, qa, ua, qb, ub)
        after = vis_naive(pa, va, qa2, ua2, f) + vis_naive(pb, vb, qb2, ub2, f)
        # Eq. 4.13: the sum never decreases; strictly iff a landmark moved; gain = difference.
        assert after >= before - 1e-12
        assert out.gain == pytest.approx(after - before, abs=1e-12)
        assert out.success == bool(out.a_to_b.any() or out.b_to_a.any())
        if out.success:
            assert out.gain > 0 and after > before
            n_success += 1
        else:
            assert out.gain == 0.0
            n_fail += 1
        # Union preserved, nothing duplicated: the multiset of landmarks is unchanged.
        all_before = np.vstack([np.hstack([qa, ua]), np.hstack([qb, ub])])
        all_after = np.vstack([np.hstack([qa2, ua2]), np.hstack([qb2, ub2])])
        assert all_before.shape == all_after.shape
        np.testing.assert_array_equal(all_before[_row_order(all_before)],
                                      all_after[_row_order(all_after)])
        # Conditions 4.13: every landmark ends with an agent that sees it at least as well.
        for j in range(len(qa2)):
            assert vis_one(pa, va, qa2[j], ua2[j], f) >= vis_one(pb, vb, qa2[j], ua2[j], f) - 1e-15
        for j in range(len(qb2)):
            assert vis_one(pb, vb, qb2[j], ub2[j], f) >= vis_one(pa, va, qb2[j], ub2[j], f) - 1e-15
        # Idempotent: trading again right away moves nothing.
        again = trade_landmarks(pa, va, qa2, ua2, pb, vb, qb2, ub2, d_opt)
        assert not again.success and again.gain == 0.0
    assert n_success > 150 and n_fail > 50, (n_success, n_fail)


def test_ties_are_not_traded() -> None:
    """Equal vision (e.g. 0 = 0: neither agent sees the landmark, or identical poses) stays put."""
    rng = np.random.default_rng(3)
    for _ in range(200):
        d_opt, pa, va, qa, ua, pb, vb, qb, ub = random_agents(rng)
        # Landmarks both agents see from behind their surface: vis 0 for both.
        m = 5
        q = rng.uniform(-1, 1, (m, 3))
        u = np.zeros((m, 3))
        for j in range(m):
            # Normal pointing away from both cameras (if possible) → both visions 0.
            n = -(pa - q[j]) / np.linalg.norm(pa - q[j]) - (pb - q[j]) / np.linalg.norm(pb - q[j])
            u[j] = n / max(float(np.linalg.norm(n)), 1e-300)
        keep = (np.einsum("ij,ij->i", pa - q, u) <= 0) & (np.einsum("ij,ij->i", pb - q, u) <= 0)
        q, u = q[keep], u[keep]
        out = trade_landmarks(pa, va, q, u, pb, vb, q, u, d_opt)
        assert not out.success and out.gain == 0.0
        # Identical cameras: every landmark is a tie.
        out = trade_landmarks(pa, va, qa, ua, pa.copy(), va.copy(), qb, ub, d_opt)
        assert not out.success and out.gain == 0.0
    # A hand-made exact tie with positive vision: mirror-symmetric cameras.
    q = np.array([[0.0, 0.0, 0.0]])
    u = np.array([[0.0, 0.0, 1.0]])
    pa, pb = np.array([1.0, 0.0, 2.0]), np.array([-1.0, 0.0, 2.0])
    va, vb = -pa / np.linalg.norm(pa), -pb / np.linalg.norm(pb)
    out = trade_landmarks(pa, va, q, u, pb, vb, q, u, 2.0)
    assert not out.success


def test_trade_moves_landmark_to_better_viewer() -> None:
    q = np.array([[0.0, 0.0, 0.0]])
    u = np.array([[0.0, 0.0, 1.0]])
    pa, va = np.array([0.0, 0.0, 2.0]), np.array([0.0, 0.0, -1.0])  # head-on at d_opt: vis 1
    pb, vb = np.array([3.0, 0.0, 0.5]), np.array([-1.0, 0.0, 0.0])  # oblique: vis < 1
    out = trade_landmarks(pa, va, np.zeros((0, 3)), np.zeros((0, 3)), pb, vb, q, u, 2.0)
    assert out.b_to_a.tolist() == [True] and out.success
    want = 1.0 - vis_one(pb, vb, q[0], u[0], lambda r: f_exp(r, 2.0))
    assert out.gain == pytest.approx(want, rel=1e-12)


def test_partner_list_semantics() -> None:
    """Section 4.5: try partners in order; drop busy/failed ones; reset after a success;
    forget agents that left; an empty list means waiting passively (None)."""
    pl = PartnerList("b", ("a", "b", "c", "d"))
    assert pl.pending == ["a", "c", "d"]  # never oneself
    assert pl.next() == "a"
    pl.drop("a")  # busy or failed trade
    assert pl.next() == "c"
    pl.drop("zzz")  # unknown: harmless
    assert pl.pending == ["c", "d"]
    pl.reset()  # a successful trade: everybody again, in order
    assert pl.pending == ["a", "c", "d"]
    pl.forget("c")  # left the mission: gone for good, even after a reset
    assert pl.pending == ["a", "d"]
    pl.reset()
    assert pl.pending == ["a", "d"] and "c" not in pl.everyone
    pl.drop("a")
    pl.drop("d")
    assert pl.next() is None  # wait passively
    pl.reset(["a", "b", "e"])  # membership change
    assert pl.pending == ["a", "e"] and pl.next() == "a"
    alone = PartnerList("x", ("x",))
    assert alone.next() is None


def test_occluded_landmarks_count_zero_in_the_trade() -> None:
    """A wall hides A's landmark 0 from A (clear_a False) although A faces it better than B
    does: with the masks it goes to B, which sees it; without them it stays. A landmark
    hidden from B never goes to B; the gain counts only what the new owner sees."""
    p_a, v_a = np.array([0.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])
    p_b, v_b = np.array([0.0, 3.0, 0.0]), np.array([1.0, 0.0, 0.0])
    q_a = np.array([[2.0, 0.5, 0.0], [2.0, -0.5, 0.0]])
    u_a = np.array([[-1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    q_b, u_b = np.zeros((0, 3)), np.zeros((0, 3))
    plain = trade_landmarks(p_a, v_a, q_a, u_a, p_b, v_b, q_b, u_b, 2.0)
    assert not plain.success  # A sees both better than B
    clear_a = np.array([False, True])
    masked = trade_landmarks(p_a, v_a, q_a, u_a, p_b, v_b, q_b, u_b, 2.0,
                             clear_a=clear_a, clear_b=np.array([True, True]))
    assert masked.a_to_b.tolist() == [True, False]
    f = lambda r: f_exp(r, 2.0)  # noqa: E731
    assert masked.gain == pytest.approx(vis_one(p_b, v_b, q_a[0], u_a[0], f), rel=1e-12)
    hidden_from_b = trade_landmarks(p_a, v_a, q_a, u_a, p_b, v_b, q_b, u_b, 2.0,
                                    clear_a=clear_a, clear_b=np.array([False, True]))
    assert not hidden_from_b.success  # nobody who can see it is better placed: it stays
