"""A capture matrix kept by rows: C (K, m), viewpoint k captures landmark j, stored sparse
(CSR), as the capture table's builder makes it (:mod:`agent.structure.inspection`) and
:class:`agent.core.inspection.CaptureTable` keeps it: 8 bytes per capture instead of K·m bytes
dense, which a 10^5-landmark table could not hold."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Mask = NDArray[np.bool_]

__all__ = ["CaptureRows"]


@dataclass(frozen=True)
class CaptureRows:
    """A capture matrix C (K, m) stored by rows (CSR): viewpoint k captures the landmarks
    ``indices[indptr[k]:indptr[k + 1]]`` (ascending). K·(8 bytes) + 8 bytes per capture
    instead of K·m bytes dense."""

    indptr: NDArray[np.intp]  #: (K + 1,) row starts in ``indices``
    indices: NDArray[np.intp]  #: landmark columns of the captures, by row
    m: int  #: landmarks (columns)

    @property
    def shape(self) -> tuple[int, int]:
        """(K, m)."""
        return self.indptr.size - 1, self.m

    @property
    def nnz(self) -> int:
        """Captures in all (True entries of C)."""
        return int(self.indptr[-1])

    @staticmethod
    def from_dense(C: Mask) -> CaptureRows:
        """The rows of a dense C (K, m)."""
        k, j = np.nonzero(C)
        return CaptureRows.from_pairs(k, j, C.shape[0], C.shape[1])

    @staticmethod
    def from_pairs(k: NDArray[np.intp], j: NDArray[np.intp], K: int, m: int) -> CaptureRows:
        """The rows of the captures (k, j), given sorted by (k, j) without repeats."""
        indptr = np.zeros(K + 1, dtype=np.intp)
        np.cumsum(np.bincount(k, minlength=K), out=indptr[1:])
        return CaptureRows(indptr, np.asarray(j, dtype=np.intp), int(m))

    def pairs(self) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """Every capture as (row k, column j), sorted by (k, j)."""
        K = self.indptr.size - 1
        return np.repeat(np.arange(K, dtype=np.intp), np.diff(self.indptr)), self.indices

    def dense(self) -> Mask:
        """C (K, m) as a dense bool matrix."""
        out = np.zeros(self.shape, dtype=np.bool_)
        out[self.pairs()] = True
        return out

    def row(self, k: int) -> Mask:
        """Row k of C (m,): the landmarks viewpoint k captures."""
        out = np.zeros(self.m, dtype=np.bool_)
        out[self.indices[self.indptr[k]:self.indptr[k + 1]]] = True
        return out

    def any_of(self, rows: Mask) -> Mask:
        """Landmarks (m,) captured by some viewpoint of ``rows`` (K,): ``C[rows].any(0)``."""
        k, j = self.pairs()
        out = np.zeros(self.m, dtype=np.bool_)
        out[j[rows[k]]] = True
        return out

    def columns(self) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """C by columns, as :func:`agent.core.tours.capturers` gives it: (indptr (m + 1,),
        rows), the rows of each column ascending."""
        k, j = self.pairs()
        order = np.argsort(j, kind="stable")  # rows stay ascending within a column
        indptr = np.zeros(self.m + 1, dtype=np.intp)
        np.cumsum(np.bincount(j, minlength=self.m), out=indptr[1:])
        return indptr, k[order]
