"""Which viewpoints to visit and in what order (beyond the thesis: inspection tours).

Pure numpy, deterministic. Points are positions [m; world ENU]; a *tour* is an open path from
a drone's position through its viewpoints (the drone does not return: the mission ends when
the last landmark is captured). Lengths are straight-line [m]; a tour's flight time is its
length over the speed limit ṗ_lim.

- :func:`greedy_cover`: fewest viewpoints (greedy set cover) that capture every landmark of a
  set, each landmark credited to the first chosen viewpoint that captures it;
- :func:`order_tour`: nearest neighbour, then 2-opt moves for an open path;
- :func:`split_tours`: viewpoints shared among drones so that the longest tour is short
  (Voronoi start, then moves off the longest tour while it shortens).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]
Index = NDArray[np.intp]

#: A move must shorten the longest tour by this much [m] to be taken (no churn on ties).
MIN_GAIN = 1e-6


def capturers(C: Mask) -> tuple[Index, Index]:
    """C (K, m) by columns: (indptr (m + 1,), rows): landmark j is captured by the rows
    ``rows[indptr[j]:indptr[j + 1]]``."""
    j, k = np.nonzero(C.T)
    indptr = np.zeros(C.shape[1] + 1, dtype=np.intp)
    np.cumsum(np.bincount(j, minlength=C.shape[1]), out=indptr[1:])
    return indptr, k.astype(np.intp)


def _rows_of(cols: tuple[Index, Index], mask: Mask) -> Index:
    """Every row capturing a landmark of ``mask`` (with repeats), from :func:`capturers`."""
    indptr, rows = cols
    j = np.flatnonzero(mask)
    lengths = indptr[j + 1] - indptr[j]
    starts = np.repeat(indptr[j] - np.concatenate([[0], np.cumsum(lengths)[:-1]]), lengths)
    return rows[starts + np.arange(int(lengths.sum()))]


class Rows(Protocol):
    """A capture matrix C (K, m) kept by rows (:class:`agent.core.capture_rows.CaptureRows`)."""

    @property
    def shape(self) -> tuple[int, int]: ...

    def row(self, k: int) -> Mask: ...


def greedy_cover(C: Mask | Rows, need: Mask, value: Array | None = None,
                 cols: tuple[Index, Index] | None = None, exclude: Mask | None = None
                 ) -> tuple[Index, Index]:
    """Greedy set cover: viewpoints (rows of C (K, m), C[k, j] = viewpoint k captures
    landmark j; dense, or kept by rows), never the ``exclude``d rows, until every needed
    landmark some row captures is captured; ties go to the larger ``value`` (K,). ``cols``
    (:func:`capturers` of C; needed for C kept by rows) makes the cost proportional to the
    captures of the needed landmarks, not to K·m.
    Returns (chosen rows in order, credited row per landmark or -1)."""
    K, m = C.shape
    if cols is None:
        if not isinstance(C, np.ndarray):
            raise ValueError("greedy_cover: a capture matrix kept by rows needs its columns")
        cols = capturers(C)
    row = C.__getitem__ if isinstance(C, np.ndarray) else C.row
    credit = np.full(m, -1, dtype=np.intp)
    left = need & (np.diff(cols[0]) > 0)
    chosen: list[int] = []
    if not left.any():
        return np.zeros(0, dtype=np.intp), credit
    counts = np.bincount(_rows_of(cols, left), minlength=K).astype(np.float64)
    if exclude is not None:
        counts[exclude] = -np.inf
    tie = np.zeros(K) if value is None else value / (1.0 + float(np.abs(value).max()))
    while left.any():
        k = int(np.argmax(counts + tie))
        if counts[k] < 0.5:  # what is left only excluded rows capture
            break
        new = left & row(k)
        credit[new] = k
        chosen.append(k)
        left &= ~new
        counts -= np.bincount(_rows_of(cols, new), minlength=K)
    return np.asarray(chosen, dtype=np.intp), credit


def path_length(start: Array, pts: Array) -> float:
    """Length [m] of the open path start → pts[0] → … → pts[-1]."""
    if pts.shape[0] == 0:
        return 0.0
    seq = np.vstack([start[None, :], pts])
    return float(np.linalg.norm(np.diff(seq, axis=0), axis=1).sum())


def _nearest_neighbour(D: Array) -> Index:
    """Order of nodes 1..n visited greedily from node 0 over the distance matrix D."""
    n = D.shape[0] - 1
    seen = np.zeros(n + 1, dtype=bool)
    seen[0] = True
    order = []
    cur = 0
    for _ in range(n):  # one step per viewpoint (not per landmark)
        d = np.where(seen, np.inf, D[cur])
        cur = int(np.argmin(d))
        seen[cur] = True
        order.append(cur)
    return np.asarray(order, dtype=np.intp)


def _two_opt(D: Array, path: Index, rounds: int = 200) -> Index:
    """2-opt for an open path 0 → path: reverse the segment path[i..j] while the best such
    reversal shortens it (all (i, j) evaluated at once)."""
    path = path.copy()
    n = path.size
    if n < 2:
        return path
    for _ in range(rounds):
        x = np.concatenate([[0], path])  # node sequence, x[0] = start
        i = np.arange(1, n + 1)[:, None]
        j = np.arange(1, n + 1)[None, :]
        prev, first, last = x[i - 1], x[i], x[j]
        old = D[prev, first]
        new = D[prev, last]
        nxt = np.minimum(j + 1, n)
        inner = j < n
        old = old + np.where(inner, D[last, x[nxt]], 0.0)
        new = new + np.where(inner, D[first, x[nxt]], 0.0)
        gain = np.where(j > i, old - new, 0.0)
        a, b = np.unravel_index(int(np.argmax(gain)), gain.shape)
        if gain[a, b] <= MIN_GAIN:
            break
        path[a:b + 1] = path[a:b + 1][::-1].copy()
    return path


def order_tour(start: Array, pts: Array) -> Index:
    """Visiting order (indices into pts (k, 3)) of an open tour from ``start`` (3,) [m]:
    nearest neighbour improved by 2-opt."""
    k = pts.shape[0]
    if k == 0:
        return np.zeros(0, dtype=np.intp)
    nodes = np.vstack([start[None, :], pts])
    D = np.linalg.norm(nodes[:, None, :] - nodes[None, :, :], axis=2)
    return _two_opt(D, _nearest_neighbour(D)) - 1


def _tour(start: Array, pts: Array, members: Index) -> tuple[Index, float]:
    order = members[order_tour(start, pts[members])]
    return order, path_length(start, pts[order])


def split_tours(starts: Array, pts: Array, rounds: int = 200) -> tuple[Index, Array]:
    """Assign viewpoints pts (k, 3) to drones at ``starts`` (n, 3) [m] so that the longest
    open tour is short; returns (drone index per viewpoint (k,), tour lengths (n,) [m])."""
    n, k = starts.shape[0], pts.shape[0]
    if k == 0:
        return np.zeros(0, dtype=np.intp), np.zeros(n)
    label = np.argmin(np.linalg.norm(pts[:, None, :] - starts[None, :, :], axis=2), axis=1)
    tours = [_tour(starts[i], pts, np.flatnonzero(label == i)) for i in range(n)]
    for _ in range(rounds):
        L = np.array([t[1] for t in tours])
        a = int(np.argmax(L))
        best: tuple[float, int, int] | None = None  # (new longest, point, to drone)
        seq_a = tours[a][0]
        for b in range(n):  # loop over drones; the insertion costs are vectorised
            if b == a:
                continue
            nodes_b = np.vstack([starts[b][None, :], pts[tours[b][0]]])
            # Cheapest insertion of each of a's points into b's path (between or at the end).
            x = pts[seq_a]
            d_in = np.linalg.norm(x[:, None, :] - nodes_b[None, :, :], axis=2)  # (ka, kb+1)
            edge = np.linalg.norm(np.diff(nodes_b, axis=0), axis=1)
            ins = np.full(seq_a.size, np.inf)
            if edge.size:
                ins = (d_in[:, :-1] + d_in[:, 1:] - edge[None, :]).min(axis=1)
            ins = np.minimum(ins, d_in[:, -1])
            # Removal saving of each of a's points from a's path.
            nodes_a = np.vstack([starts[a][None, :], pts[seq_a]])
            dd = np.linalg.norm(np.diff(nodes_a, axis=0), axis=1)
            after = np.r_[dd[1:], 0.0]
            skip = np.r_[np.linalg.norm(nodes_a[2:] - nodes_a[:-2], axis=1), 0.0]
            save = dd + after - np.where(np.arange(seq_a.size) < seq_a.size - 1, skip, 0.0)
            new_max = np.maximum(L[a] - save, L[b] + ins)
            others = np.delete(L, [a, b]).max(initial=0.0)
            new_max = np.maximum(new_max, others)
            c = int(np.argmin(new_max))
            if new_max[c] < L[a] - MIN_GAIN and (best is None or new_max[c] < best[0]):
                best = (float(new_max[c]), int(seq_a[c]), b)
        if best is None:
            break
        _, point, b = best
        trial = label.copy()
        trial[point] = b
        ta = _tour(starts[a], pts, np.flatnonzero(trial == a))
        tb = _tour(starts[b], pts, np.flatnonzero(trial == b))
        if max(ta[1], tb[1]) >= L[a] - MIN_GAIN:
            break
        label, tours[a], tours[b] = trial, ta, tb
    return label.astype(np.intp), np.array([t[1] for t in tours])
