"""The line-of-sight test's type: what a layer that holds a structure's mesh hands the pure
decisions of :mod:`agent.core.viewpoints` (visibility "occlusion")."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]
Pairs = tuple[NDArray[np.intp], NDArray[np.intp]]

#: (P (K, 3), q (m, 3), u (m, 3) [m; world ENU], pairs (k rows, j rows)) → for each pair
#: whether the segment P[k] → q[j] is clear of the structure.
SightFn = Callable[[Array, Array, Array, Pairs], Mask]
