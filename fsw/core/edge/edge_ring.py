"""Ring helpers of the polygon edge fit (``fsw.core.edge.edge.fit_polygon``, docs/algorithm.md §2):
a closed ring resampled at a step, and runs of flagged vertices along it bridged over short
gaps."""

from __future__ import annotations

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry import LineString

F64 = NDArray[np.float64]


def densify_ring(ring: F64, step: float) -> F64:
    """The closed ``ring`` resampled every ``step`` (at least its two ends)."""
    line = LineString(ring)
    n = max(2, int(np.ceil(line.length / step)) + 1)
    return np.asarray(shapely.get_coordinates(
        shapely.line_interpolate_point(line, np.linspace(0.0, line.length, n))))


def bridge_runs(ring: F64, flag: NDArray[np.bool_], gap_m: float) -> NDArray[np.bool_]:
    """``flag`` (one per vertex of the closed ``ring``) with every unflagged gap between two
    flagged vertices whose path along the ring is shorter than ``gap_m`` flagged too."""
    n = ring.shape[0] - 1  # ring[-1] repeats ring[0]
    f = flag[:n].copy()
    if f.all() or not f.any():
        return flag
    seg = np.hypot(*(ring[1:] - ring[:-1]).T)  # seg[i]: vertex i to i + 1
    start = int(np.argmax(f))  # walk the ring from a flagged vertex
    order = (start + np.arange(n + 1)) % n
    last = 0  # position (in ``order``) of the last flagged vertex
    for k in range(1, n + 1):
        if f[order[k]]:
            if k - last > 1 and seg[order[last:k]].sum() < gap_m:
                f[order[last + 1:k]] = True
            last = k
    out = flag.copy()
    out[:n] = f
    out[n:] = f[0]
    return out
