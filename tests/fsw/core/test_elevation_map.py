"""Elevation-map fusion (docs/algorithm.md §1.1, §3.4, §4): properties and the reduction."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap, FusionConfig, TeamElevation

GRID = MapGrid(0.0, 0.0, 0.1, 4, 3)
CELL_XY = (0.15, 0.15)  # cell [1, 1]


def one_point_merge(m: ElevationMap, z: float, var: float) -> None:
    m.merge(np.array([[CELL_XY[0], CELL_XY[1], z]]), var_z=np.array([var]))


meas = st.tuples(st.floats(-0.05, 0.05), st.floats(1e-4, 4e-4))


@settings(max_examples=60, deadline=None)
@given(st.lists(meas, min_size=2, max_size=8), st.randoms(use_true_random=False),
       st.floats(0.0, 0.9))
def test_fusion_is_order_independent(ms: list[tuple[float, float]], rnd, c: float) -> None:
    """Issue 4, done-when 6: inlier measurements fused in any order give the same cell, the
    closed form of §1.1 (z the inverse-variance mean; var = (1-c)/sum(1/v) + c min(v), which
    for a view correlation c = 0 is the plain 1/sum(1/v))."""
    cfg = FusionConfig(gate_sigma=100.0, n_max=100, view_correlation=c)
    a, b = ElevationMap(GRID, cfg), ElevationMap(GRID, cfg)
    shuffled = list(ms)
    rnd.shuffle(shuffled)
    for z, v in ms:
        one_point_merge(a, z, v)
    for z, v in shuffled:
        one_point_merge(b, z, v)
    assert a.z[1, 1] == pytest.approx(b.z[1, 1], abs=1e-12)
    assert a.var[1, 1] == pytest.approx(b.var[1, 1], rel=1e-9)
    w = np.array([1.0 / v for _, v in ms])
    zs = np.array([z for z, _ in ms])
    assert a.z[1, 1] == pytest.approx(float((w * zs).sum() / w.sum()), abs=1e-12)
    expect = (1 - c) / w.sum() + c * min(v for _, v in ms)
    assert a.var[1, 1] == pytest.approx(float(expect), rel=1e-9)
    assert a.n[1, 1] == len(ms)


@settings(max_examples=80, deadline=None)
@given(st.floats(-1, 1), st.floats(1e-6, 1.0), st.floats(1e-6, 1.0), st.floats(-2.9, 2.9))
def test_variance_never_increases_on_an_inlier(z0: float, v0: float, vm: float, k: float) -> None:
    """Issue 4, done-when 6: an inlier never increases the variance (and n grows by one)."""
    m = ElevationMap(GRID, FusionConfig(gate_sigma=3.0, max_var_m2=10.0))
    one_point_merge(m, z0, v0)
    before = m.var[1, 1]
    zm = z0 + k * math.sqrt(v0 + vm)  # inside the 3-sigma gate
    one_point_merge(m, zm, vm)
    assert m.var[1, 1] <= before
    assert m.var[1, 1] <= vm + 1e-15
    assert m.n[1, 1] == 2 and m.outliers[1, 1] == 0
    lo, hi = min(z0, zm), max(z0, zm)
    assert lo - 1e-12 <= m.z[1, 1] <= hi + 1e-12


@settings(max_examples=80, deadline=None)
@given(st.floats(-1, 1), st.floats(1e-6, 0.01), st.floats(1e-6, 0.01), st.floats(3.2, 50.0),
       st.sampled_from([-1.0, 1.0]))
def test_outlier_gate_refuses_and_inflates(z0: float, v0: float, vm: float, k: float,
                                           sign: float) -> None:
    """Issue 4, done-when 6: a measurement beyond the gate is counted, not averaged in, and
    inflates the cell's variance by outlier_var_factor."""
    cfg = FusionConfig(gate_sigma=3.0, outlier_var_factor=4.0)
    m = ElevationMap(GRID, cfg)
    one_point_merge(m, z0, v0)
    stats = m.merge(np.array([[CELL_XY[0], CELL_XY[1], z0 + sign * k * math.sqrt(v0 + vm)]]),
                    var_z=np.array([vm]))
    assert stats.outliers == 1
    assert m.z[1, 1] == pytest.approx(z0, abs=1e-12)
    assert m.var[1, 1] == pytest.approx(4.0 * v0)
    assert m.n[1, 1] == 1 and m.outliers[1, 1] == 1


def test_repeated_outliers_eventually_accept_a_real_change() -> None:
    """§1.1 choice: a cell that really changed is accepted after a few inflations."""
    m = ElevationMap(GRID, FusionConfig(gate_sigma=3.0, outlier_var_factor=4.0))
    one_point_merge(m, 0.0, 1e-4)
    for _ in range(6):
        one_point_merge(m, 0.3, 1e-4)
    assert m.z[1, 1] > 0.25 and m.outliers[1, 1] >= 1


@settings(max_examples=60, deadline=None)
@given(st.floats(-1, 1), st.floats(1e-4, 0.05), st.floats(0.01, 0.99), st.floats(3.2, 50.0))
def test_where_agents_meet_a_tighter_refused_height_above_holds_the_cell(
        z0: float, v0: float, ratio: float, k: float) -> None:
    """§8, fusion from several agents: one agent's view of a cell, low and overconfident (the
    face under a lip, seen from below), then the other's, beyond the gate, above it and with a
    smaller variance: the shared grid holds the second, a one-agent grid keeps the first (§1.1).
    Refused as §1.1 everywhere: the same measurement below the cell, or one with a larger variance."""
    cfg = FusionConfig(gate_sigma=3.0, outlier_var_factor=4.0)
    vm = ratio * v0
    zm = z0 + k * math.sqrt(v0 + vm)
    shared, alone = TeamElevation(GRID, cfg), ElevationMap(GRID, cfg)
    for m in (shared, alone):
        one_point_merge(m, z0, v0)
        one_point_merge(m, zm, vm)
        assert m.n[1, 1] == 1 and m.outliers[1, 1] == 1
    assert shared.z[1, 1] == pytest.approx(zm, abs=1e-12) and shared.var[1, 1] == pytest.approx(vm)
    assert alone.z[1, 1] == pytest.approx(z0, abs=1e-12) and alone.var[1, 1] == pytest.approx(4.0 * v0)
    for first, second in (((z0, v0), (2 * z0 - zm, vm)), ((zm, vm), (z0, v0)), ((z0, vm), (zm, v0))):
        m = TeamElevation(GRID, cfg)
        one_point_merge(m, *first)
        one_point_merge(m, *second)
        assert m.z[1, 1] == pytest.approx(first[0], abs=1e-12) and m.var[1, 1] == pytest.approx(4.0 * first[1])


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000), st.floats(0.0, 1.0))
def test_vectorized_reduction_matches_a_loop(seed: int, rho: float) -> None:
    """The bincount reduction equals a per-cell reference loop (k points, correlation rho)."""
    rng = np.random.default_rng(seed)
    n = 60
    xyz = np.column_stack([rng.uniform(-0.05, 0.45, n), rng.uniform(-0.05, 0.35, n),
                           rng.normal(0, 0.01, n)])
    v = rng.uniform(1e-5, 1e-4, n)
    m = ElevationMap(GRID, FusionConfig(point_correlation=rho, subcell_term=False))
    stats = m.merge(xyz, var_z=v)
    iy, ix, inside = GRID.cell_index(xyz[:, 0], xyz[:, 1])
    assert stats.points_used == inside.sum()
    for cy in range(GRID.ny):
        for cx in range(GRID.nx):
            sel = inside & (iy == cy) & (ix == cx)
            if not sel.any():
                assert math.isnan(m.z[cy, cx]) and m.var[cy, cx] == math.inf
                assert m.n[cy, cx] == 0
                continue
            w = 1.0 / v[sel]
            k = sel.sum()
            assert m.z[cy, cx] == pytest.approx((w * xyz[sel, 2]).sum() / w.sum(), abs=1e-12)
            assert m.var[cy, cx] == pytest.approx((1 + (k - 1) * rho) / w.sum(), rel=1e-9)
            assert m.n[cy, cx] == 1


def test_unknown_cells_and_count_cap() -> None:
    """§1: unknown = NaN/inf/0; n counts views and is capped by n_max."""
    m = ElevationMap(GRID, FusionConfig(n_max=3, view_correlation=0.0))
    assert np.isnan(m.z).all() and np.isinf(m.var).all() and not m.mapped.any()
    assert (m.interest == 1.0).all() and (m.misses == 0).all()
    for _ in range(5):
        one_point_merge(m, 0.0, 1e-4)
    assert m.n[1, 1] == 3 and m.mapped.sum() == 1
    assert m.var[1, 1] == pytest.approx(1e-4 / 5)  # the variance keeps shrinking past n_max


def test_bad_points_are_dropped_not_merged() -> None:
    """Bad input: NaN, negative or huge variance, or off-grid points never touch the map."""
    m = ElevationMap(GRID)
    xyz = np.array([[0.15, 0.15, np.nan], [0.15, 0.15, 0.0], [9.0, 9.0, 0.0], [0.25, 0.15, 0.0],
                    [0.05, 0.05, 0.0]])
    stats = m.merge(xyz, var_z=np.array([1e-4, -1.0, 1e-4, 1e6, np.nan]))
    assert stats.points_in == 5 and stats.points_used == 0 and not m.mapped.any()
    with pytest.raises(ValueError, match="rows"):
        m.merge(np.zeros((3, 3)), var_z=np.ones(2))
    with pytest.raises(ValueError, match="var_z or cov"):
        m.merge(np.zeros((3, 3)))


def test_misses_decay_interest_by_visibility() -> None:
    """§3.4/§4: cells expected visible without a point get IF *= exp(-beta P_V); misses count
    those with P_V >= threshold; a cell that got a point is untouched."""
    cfg = FusionConfig(interest_beta=2.0, miss_pv_threshold=0.5)
    m = ElevationMap(GRID, cfg)
    pv = np.zeros(GRID.shape)
    pv[1, 1] = 1.0  # gets a point below
    pv[0, 0] = 0.9
    pv[2, 3] = 0.1  # likely occluded: barely penalised, no miss
    stats = m.merge(np.array([[0.15, 0.15, 0.0]]), var_z=np.array([1e-4]), p_visible=pv)
    assert stats.misses == 1
    assert m.misses[0, 0] == 1 and m.misses[2, 3] == 0 and m.misses[1, 1] == 0
    assert m.interest[0, 0] == pytest.approx(math.exp(-1.8))
    assert m.interest[2, 3] == pytest.approx(math.exp(-0.2))
    assert m.interest[1, 1] == 1.0 and m.interest[0, 1] == 1.0
    mask = np.zeros(GRID.shape, bool)
    mask[0, 0] = True
    m.merge(np.zeros((0, 3)), var_z=np.zeros(0), p_visible=mask)
    assert m.misses[0, 0] == 2 and m.interest[0, 0] == pytest.approx(math.exp(-3.8))
    with pytest.raises(ValueError, match="shape"):
        m.merge(np.zeros((0, 3)), var_z=np.zeros(0), p_visible=np.ones((2, 2)))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        m.merge(np.zeros((0, 3)), var_z=np.zeros(0), p_visible=np.full(GRID.shape, 2.0))


def test_slope_term_inflates_variance_on_slopes_only() -> None:
    """§1.2: with full covariances a horizontal error on a slope adds vertical variance."""
    grid = MapGrid(0.0, 0.0, 0.1, 10, 10)
    xs, ys = np.meshgrid(np.arange(10) * 0.1 + 0.05, np.arange(10) * 0.1 + 0.05)
    cov = np.zeros((100, 3, 3))
    cov[:, 0, 0] = cov[:, 1, 1] = 0.01**2
    cov[:, 2, 2] = 0.002**2
    flat = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(100)])
    slope = flat.copy()
    slope[:, 2] = 0.5 * slope[:, 0]  # gradient 0.5 along x
    a, b = ElevationMap(grid), ElevationMap(grid)
    a.merge(flat, cov=cov)
    b.merge(slope, cov=cov)
    assert a.var[5, 5] == pytest.approx(0.002**2)
    assert b.var[5, 5] == pytest.approx(0.002**2 + 0.25 * 0.01**2, rel=1e-6)
    c = ElevationMap(grid, FusionConfig(footprint_term=True))
    c.merge(slope, cov=cov)
    assert c.var[5, 5] == pytest.approx(0.002**2 + 0.25 * 0.01**2 + 0.25 * 0.1**2 / 12, rel=1e-6)
    # a horizontal error along the ray can cancel on a slope facing the camera; a noisy
    # gradient must not talk the variance below P_zz
    cov_facing = cov.copy()
    cov_facing[:, 0, 2] = cov_facing[:, 2, 0] = 0.9 * 0.01 * 0.002
    d = ElevationMap(grid)
    d.merge(slope, cov=cov_facing)
    assert d.var[5, 5] >= 0.002**2


def test_common_pose_variance_is_not_averaged_away() -> None:
    """§1.2: the pose part of the variance is shared by every point of a view, so a cell
    with k points keeps all of it, while the stereo part shrinks as (1 + (k-1) rho) / k."""
    cfg = FusionConfig(point_correlation=0.0, subcell_term=False, slope_term=False,
                       footprint_term=False)
    k = 16
    xyz = np.column_stack([np.full(k, 0.15), np.full(k, 0.15), np.zeros(k)])
    cov = np.zeros((k, 3, 3))
    common = np.zeros((k, 3, 3))
    common[:, 2, 2] = 4e-4
    cov[:, 2, 2] = 1e-4 + 4e-4
    m = ElevationMap(GRID, cfg)
    m.merge(xyz, cov=cov, cov_common=common)
    assert m.var[1, 1] == pytest.approx(1e-4 / k + 4e-4)
    with pytest.raises(ValueError, match="cov_common needs cov"):
        m.merge(xyz, var_z=np.ones(k), cov_common=common)


@pytest.mark.parametrize("pose_common", [True, False])
def test_views_share_their_pose_variance(pose_common: bool) -> None:
    """§1.1, §1.2: every view of a map carries its frame error (the first view's attitude, the
    later ones registered to it), so with ``pose_common`` the pose part of a cell's variance
    stays whole over views while the stereo part averages down past ``view_correlation``."""
    c, S, P = 0.4, 1e-4, 4e-4
    cfg = FusionConfig(point_correlation=0.0, subcell_term=False, slope_term=False, footprint_term=False,
                       view_correlation=c, pose_common=pose_common, gate_sigma=100.0)
    xyz = np.array([[0.15, 0.15, 0.0]])
    cov = np.zeros((1, 3, 3))
    cov[:, 2, 2] = S + P
    common = np.zeros((1, 3, 3))
    common[:, 2, 2] = P
    m = ElevationMap(GRID, cfg)
    for z in (0.0, 0.01):
        m.merge(xyz + [0.0, 0.0, z], cov=cov, cov_common=common)
    if pose_common:
        assert m.var[1, 1] == pytest.approx((1 - c) * S / 2 + c * S + P)
    else:
        assert m.var[1, 1] == pytest.approx((1 - c) * (S + P) / 2 + c * (S + P))
        assert m.var[1, 1] < P + S / 2
    assert m.z[1, 1] == pytest.approx(0.005)


def test_subcell_spread_beyond_noise_adds_variance() -> None:
    """A cell whose points spread far more than their noise (a step inside the cell) gets
    that spread as variance; points that agree within their noise add nothing."""
    cfg = FusionConfig(point_correlation=1.0, view_correlation=0.0)
    agree = np.column_stack([np.full(10, 0.15), np.full(10, 0.15), np.zeros(10)])
    step = agree.copy()
    step[:5, 2] = 0.2  # half the points on top of a 20 cm step
    a, b = ElevationMap(GRID, cfg), ElevationMap(GRID, cfg)
    a.merge(agree, var_z=np.full(10, 1e-4))
    b.merge(step, var_z=np.full(10, 1e-4))
    assert a.var[1, 1] == pytest.approx(1e-4)
    assert b.z[1, 1] == pytest.approx(0.1)
    spread = 0.1**2 * 10 / 9
    assert b.var[1, 1] == pytest.approx(1e-4 + spread - 1e-4 * 10 / 9, rel=1e-6)



REACH = FusionConfig(source_reach_sigma=2.0)  # as the Cliff-bot's views use it (fsw.tasks.cliffbot.sensing)


def _along_the_foot(lateral_sigma: float, strays: bool = True) -> tuple[MapGrid, np.ndarray, np.ndarray, np.ndarray,
                                                                        tuple[int, int]]:
    """A view along a face's foot (docs/algorithm.md §1.2): the camera looks along +x beside a face
    that rises at slope 4 (76 deg) from the floor at y = 0.3 m; it sees the floor up to y = 0.12 m
    and the face. Its points carry a range error along the ray and a lateral one across it,
    horizontal (the pose's heading error at range). With ``strays``, face points from y = 0.36 m
    (0.24 m up the face) land 16.5 cm across the sight line, in a row of floor cells (y = 0.18 to
    0.21 m, truth 0) whose neighbours across the row the view did not measure: their own gradient
    is flat. Returns the grid, points, covariances, the eye and one stray cell."""
    grid = MapGrid(0.0, 0.0, 0.03, 80, 30)
    eye = np.array([-1.0, 0.2, 0.45])
    xs = np.arange(0.6, 2.0, 0.01)
    rows = [np.column_stack([xs, np.full(xs.size, y), np.zeros(xs.size)]) for y in np.arange(0.005, 0.12, 0.03)]
    rows += [np.column_stack([xs, np.full(xs.size, y), np.full(xs.size, 4.0 * (y - 0.3))])
             for y in np.arange(0.305, 0.6, 0.03)]
    if strays:
        sx = np.arange(1.0, 1.4, 0.01)
        rows.append(np.column_stack([sx, np.full(sx.size, 0.195), np.full(sx.size, 0.24)]))
    pts = np.vstack(rows)
    u = pts - eye
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    h = np.column_stack([-u[:, 1], u[:, 0], np.zeros(len(u))])
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    cov = (0.02**2 * u[:, :, None] * u[:, None, :] + lateral_sigma**2 * h[:, :, None] * h[:, None, :]
           + 0.005**2 * np.eye(3)[None])
    return grid, pts, cov, eye, (6, 40)


def test_a_point_off_a_steep_surface_takes_that_surfaces_slope() -> None:
    """§1.2: face points carried across the line of sight onto floor cells keep the face's height
    there: their variance takes the slope of the steepest surface their lateral error reaches, so
    those cells' heights are within the gate of their truth (0). The floor cells' own gradient
    (flat: the view measured nothing beside them) put them tens of sigma off (the old variance:
    ``source_reach_sigma = 0``, or no eye)."""
    grid, pts, cov, eye, cell = _along_the_foot(lateral_sigma=0.08)
    honest = ElevationMap(grid, REACH)
    honest.merge(pts, cov=cov, eye=eye)
    old = ElevationMap(grid, REACH)
    old.merge(pts, cov=cov)
    off = ElevationMap(grid, FusionConfig(source_reach_sigma=0.0))
    off.merge(pts, cov=cov, eye=eye)
    assert old.z[cell] == pytest.approx(0.24) and honest.z[cell] == pytest.approx(0.24)
    assert old.var[cell] == off.var[cell]
    assert old.z[cell] / math.sqrt(old.var[cell]) > 10.0
    assert honest.z[cell] / math.sqrt(honest.var[cell]) < 2.0
    # far from any steep surface of the view the floor's variance is what it was
    assert honest.var[1, 40] == pytest.approx(old.var[1, 40])


def test_a_tight_lateral_error_reaches_no_steeper_surface() -> None:
    """The reach scales with the lateral error: floor points whose error across the sight line is
    a millimetre do not take the face seven cells away; with 8 cm they do."""
    tight = _along_the_foot(lateral_sigma=0.001, strays=False)
    loose = _along_the_foot(lateral_sigma=0.08, strays=False)
    got = []
    for grid, pts, cov, eye, _ in (tight, loose):
        a, b = ElevationMap(grid, REACH), ElevationMap(grid)
        a.merge(pts, cov=cov, eye=eye)
        b.merge(pts, cov=cov)
        got.append(a.var[3, 40] / b.var[3, 40])
    assert got[0] == pytest.approx(1.0) and got[1] > 10.0


def test_a_camera_centre_that_is_not_finite_is_refused() -> None:
    grid, pts, cov, _, _ = _along_the_foot(lateral_sigma=0.05)
    with pytest.raises(ValueError, match="eye"):
        ElevationMap(grid, REACH).merge(pts, cov=cov, eye=np.array([np.nan, 0.0, 0.0]))
