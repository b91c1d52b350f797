"""The face map's variance at grazing incidence (docs/algorithm.md §8.1, "The relief the view
cannot resolve"): a view whose points' error lies along the face blurs the relief, and the
variances it gives its cells must still cover their error; a second agent's better view of a
cell must not leave the fused cell worse than that view alone."""

from __future__ import annotations

import numpy as np

from fsw.core.geometry import MapGrid
from fsw.core.map.face_map import FaceElevation, relief_variance, run_merge

CELL = 0.06


def relief(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A face's relief along its normal: ridges across the dip (slope up to 0.8) and a gentler
    swell along the strike."""
    return 0.03 * np.sin(2 * np.pi * v / 0.24) + 0.02 * np.sin(2 * np.pi * u / 0.5 + 1.0)


def relief_dv(v: np.ndarray) -> np.ndarray:
    return 0.03 * 2 * np.pi / 0.24 * np.cos(2 * np.pi * v / 0.24)


COT_INCIDENCE = 1.0 / np.tan(np.radians(82.0))


def grazing_view(rng: np.random.Generator, sigma_v: float, sigma_w: float, per_cell: int = 20,
                 n: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """Points of one view over an ``n`` x ``n`` cell patch (face frame ``u, v, w``): each a true
    surface point moved along the dip by ``sigma_v`` (the depth error at grazing incidence lies
    nearly in the face) and along the normal by ``sigma_w``; their covariances."""
    m = per_cell * n * n
    u, v = rng.uniform(0, n * CELL, m), rng.uniform(0, n * CELL, m)
    seen = relief_dv(v) < COT_INCIDENCE  # looking down the dip: the ground rising along it is turned away
    u, v = u[seen], v[seen]
    m = len(u)
    w = relief(u, v) + rng.normal(0, sigma_w, m)
    v = v + rng.normal(0, sigma_v, m)
    cov = np.zeros((m, 3, 3))
    cov[:, 0, 0], cov[:, 1, 1], cov[:, 2, 2] = 1e-6, sigma_v**2, sigma_w**2
    return np.column_stack([u, v, w]), cov


def within_2_sigma(fm: FaceElevation, inner: slice = slice(2, -2)) -> float:
    g = fm.grid
    X, Y = g.centers()
    e = (fm.z - relief(X, Y))[inner, inner]
    s = np.sqrt(fm.var)[inner, inner]
    return float(np.mean(np.abs(e) <= 2 * s))


def test_a_blurred_relief_keeps_its_cells_within_two_sigma() -> None:
    """One grazing view (82 deg incidence: its points lie on the parts of the relief facing it,
    not spread over the cell): 90-99 % of its cells within 2 sigma. With the slope term on the
    view's gradient alone about 30 % of them fall outside."""
    rng = np.random.default_rng(3)
    fm = FaceElevation(MapGrid(0.0, 0.0, CELL, 30, 30))
    xyz, cov = grazing_view(rng, sigma_v=0.01, sigma_w=0.003)
    run_merge(fm, [(xyz, cov, None)], None)
    assert 0.90 <= within_2_sigma(fm) <= 0.99


def test_the_relief_term_is_zero_on_a_plane_and_grows_with_the_slope() -> None:
    g = MapGrid(0.0, 0.0, CELL, 8, 8)
    X, Y = g.centers()
    cells = np.arange(64)
    assert np.allclose(relief_variance(g, cells, np.zeros(64)), 0.0)
    v1 = relief_variance(g, cells, 0.5 * Y.reshape(-1))
    v2 = relief_variance(g, cells, 1.0 * Y.reshape(-1))
    assert np.allclose(v1, 2 * 0.25 * CELL**2 / 12) and np.allclose(v2, 4 * v1)


def test_two_views_of_a_cell_are_weighted_by_their_whole_variances() -> None:
    """A view whose variance is mostly its camera pose's (one agent's frame) and one with a
    smaller variance in all (the other agent's): the fused cell lies nearer the better one and
    holds a variance no larger than either's. Weighted by the independent parts alone (§1.1)
    the pose-dominated view would pull the cell to itself."""
    g = MapGrid(0.0, 0.0, CELL, 3, 3)
    for order in ((0, 1), (1, 0)):
        fm = FaceElevation(g)
        views = [(0.05, 0.03**2, 0.029**2), (0.0, 0.02**2, 0.0)]  # (w, variance, its pose part)
        for k in order:
            w, var, pose = views[k]
            fm._fuse(np.array([4]), np.array([w]), np.array([var]), np.array([pose]))
        z, v = float(fm.z.reshape(-1)[4]), float(fm.var.reshape(-1)[4])
        assert abs(z - 0.0) < abs(z - 0.05) / 2
        assert v <= 0.02**2 + 1e-12
