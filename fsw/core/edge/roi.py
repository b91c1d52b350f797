"""The mapped fraction of the region of interest: the cells beyond the cliff edge (docs/algorithm.md §2,
§3.6, the end criterion), estimated on every ``ROI_STRIDE``-th cell each way."""

from __future__ import annotations

from collections.abc import Generator

import numpy as np

from fsw.core.edge.edge import EdgeModel
from fsw.core.map.elevation_map import ElevationMap
from fsw.core.steps import run_to_end

ROI_STRIDE = 4  # the region-of-interest fraction is estimated on every 4th cell each way
ROI_STEP_POINTS = 2048  # cells per slice of that estimate (~10 ms on the lab's edge)


def roi_mapped_fraction(emap: ElevationMap, edge: EdgeModel) -> float:
    """Mapped fraction of the region of interest: the cells beyond the edge (§2, §3.6)."""
    return run_to_end(roi_mapped_fraction_steps(emap, edge))


def roi_mapped_fraction_steps(emap: ElevationMap, edge: EdgeModel) -> Generator[None, None, float]:
    """:func:`roi_mapped_fraction`, yielding after each ``ROI_STEP_POINTS`` cells (the signed
    distance of a cell is its own: the same values as one call)."""
    if edge.empty:
        return 0.0
    X, Y = emap.grid.centers()
    s = (slice(None, None, ROI_STRIDE), slice(None, None, ROI_STRIDE))
    pts = np.column_stack([X[s].ravel(), Y[s].ravel()])
    below = np.empty(pts.shape[0], bool)
    for a in range(0, pts.shape[0], ROI_STEP_POINTS):
        below[a:a + ROI_STEP_POINTS] = edge.signed_distance(pts[a:a + ROI_STEP_POINTS]) < 0
        yield
    if not below.any():
        return 0.0
    return float(emap.mapped[s].ravel()[below].mean())
