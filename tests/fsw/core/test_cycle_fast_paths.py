"""The sensing cycle's fast paths (issue 30 item 5) against the plain computations they replace:
the P_V kernel's window sums and sort-free orders, the ground surface on the mapped window, the
merge's P_V only off the cells the view measured."""

from __future__ import annotations

import math

import cv2
import numpy as np
from scipy.special import log_ndtr

from fsw.core.edge.edge import EdgeConfig
from fsw.core.edge.ground_plane import SURFACE_MIN_WEIGHT, ground_plane, ground_surface
from fsw.core.geometry import CameraConfig, CameraPose, MapGrid, MastConfig
from fsw.core.map.elevation_map import ElevationMap
from fsw.core.planning.nbv import predicted_visibility, predicted_visibility_steps
from fsw.core.planning.visibility import VisibilityConfig
from fsw.core.planning.visibility_kernel import (
    _NPER,
    _XMAX,
    _XMIN,
    stable_argsort,
    unique_inverse,
    window_sums_steps,
)
from fsw.core.steps import run_to_end
from hil_sim.lab.nbv_scene import panorama_map, synthetic_terrain


def test_window_sums_equal_a_plain_sum_per_target() -> None:
    """Each target's factor is exp(sum over its own window of w log Phi(a - g b)), from the
    1/256-sigma table, whatever the other targets' windows (empty ones keep their value)."""
    rng = np.random.default_rng(3)
    m, t = 5000, 400
    a = rng.uniform(1500.0, 4000.0, m).astype(np.float32)
    b = rng.uniform(0.0, 300.0, m).astype(np.float32)
    w = rng.choice(np.array([0.0, 0.03, 1.0], np.float32), m)
    win = rng.integers(0, 120, t)
    win[::7] = 0
    base = rng.integers(0, m - 120, t) + np.where(rng.random(t) < 0.1, 120 - win, 0)  # some end at m
    g = rng.uniform(-0.5, 2.0, t).astype(np.float32)
    out = np.full(t, -1.0)
    run_to_end(window_sums_steps(a, b, w, base, win, g, out))
    table = log_ndtr(np.arange(_XMIN, _XMAX, 1.0 / _NPER) + 0.5 / _NPER).astype(np.float32)
    table[-1] = 0.0
    for i in range(t):
        s = slice(base[i], base[i] + win[i])
        x = np.clip(a[s] - g[i] * b[s], 0, table.size - 1).astype(np.int32)
        expect = -1.0 if win[i] == 0 else np.exp(float(np.sum(table[x].astype(np.float64) * w[s])))
        assert np.isclose(out[i], expect, rtol=1e-4, atol=1e-30), i  # float32 sums


def test_sort_free_unique_and_radix_argsort_equal_numpys() -> None:
    """The bins' and blocks' unique values and inverse, and the stable orders of bins and
    windows, are numpy's (sorted unique; the one stable permutation), also past 16 bits."""
    rng = np.random.default_rng(5)
    for size, n in ((16, 1), (4096, 30000), (65536, 50000), (1 << 20, 5000)):
        v = rng.integers(0, size, n) if n > 1 else np.array([size - 1])
        u, inv = unique_inverse(v, size)
        ref_u, ref_inv = np.unique(v, return_inverse=True)
        assert np.array_equal(u, ref_u) and np.array_equal(inv, ref_inv.ravel())
        assert np.array_equal(stable_argsort(v), np.argsort(v, kind="stable"))
    assert stable_argsort(np.zeros(0, np.int64)).size == 0


def _surface_whole_grid(emap: ElevationMap, ground_z: float, seed: tuple[float, float],
                        cfg: EdgeConfig) -> np.ndarray:
    """The ground surface blurred over the whole grid (the computation the window replaces)."""
    ref = ground_plane(emap, ground_z, seed, cfg)
    ok = emap.mapped & np.isfinite(emap.z)
    r = np.where(ok, emap.z - ref, 0.0).astype(np.float32)
    sigma = cfg.surface_scale_m / emap.grid.cell
    bend = np.zeros(r.shape, np.float32)
    for band in (3.0, 2.0, 1.0):
        level = ok & (np.abs(r - bend) <= band * cfg.plateau_tol_m)
        wt = cv2.GaussianBlur(level.astype(np.float32), (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)
        v = cv2.GaussianBlur(np.where(level, r, 0.0).astype(np.float32), (0, 0), sigma,
                             borderType=cv2.BORDER_CONSTANT)
        bend = v / np.maximum(wt, SURFACE_MIN_WEIGHT)
    return ref + bend


def test_ground_surface_on_the_mapped_window_is_the_whole_grid_surface() -> None:
    """Rolling ground mapped in two patches (one on the grid's border) with a drop: the surface
    computed on the mapped window equals the whole grid's, cell for cell."""
    grid = MapGrid(x0=0.0, y0=0.0, cell=0.02, nx=200, ny=160)
    emap = ElevationMap(grid)
    X, Y = grid.centers()
    z = 0.04 * np.sin(X * 2.1) * np.cos(Y * 1.7) + 0.03 * X
    z[:, 120:] -= 0.6  # the drop
    mapped = np.zeros(grid.shape, bool)
    mapped[30:90, 40:150] = True
    mapped[:25, 170:] = True
    emap.z[mapped], emap.var[mapped], emap.n[mapped] = z[mapped], 1e-4, 1
    cfg = EdgeConfig()
    for seed in ((1.6, 1.2), (3.6, 0.2)):
        got = ground_surface(emap, 0.0, seed, cfg)
        assert np.array_equal(got, _surface_whole_grid(emap, 0.0, seed, cfg))
    empty = ElevationMap(grid)
    assert np.array_equal(ground_surface(empty, 0.1, (1.0, 1.0), cfg), ground_plane(empty, 0.1, (1.0, 1.0), cfg))


def test_misses_need_p_v_only_off_the_measured_cells() -> None:
    """The merge's P_V skips the cells the view measured (their P_V is never used): elsewhere
    it is the full computation's, up to float32 summation order; culling to the reach box
    changes nothing; the skipped cells read 0. ``hit_cells`` are the cells the merge fills."""
    grid = MapGrid(x0=-0.5, y0=-3.5, cell=0.04, nx=110, ny=100)
    cam = CameraConfig()
    truth, textured = synthetic_terrain(grid, seed=5)
    emap = panorama_map(truth, textured, grid, cam, MastConfig(), (0.0, 0.0, 0.0))
    pose = CameraPose.from_pan_tilt(1.0, 0.0, 1.5, -math.pi / 2, -0.6)
    full = predicted_visibility(emap, pose, cam, VisibilityConfig())
    rng = np.random.default_rng(2)
    skip = (rng.random(grid.shape) < 0.5) & (full > 0)
    part = run_to_end(predicted_visibility_steps(emap, pose, cam, VisibilityConfig(), skip=skip))
    assert (part[skip] == 0.0).all() and full[skip].max() > 0.5
    assert np.allclose(part[~skip], full[~skip], rtol=1e-5, atol=1e-6)
    # the points of a view: on and off the grid, NaN, a variance over the limit
    xyz = np.column_stack([rng.uniform(-1.0, 4.5, 3000), rng.uniform(-4.0, 0.5, 3000), rng.normal(0, 0.1, 3000)])
    xyz[::50, 2] = np.nan
    cov = np.tile(np.diag([1e-4, 1e-4, 1e-4]), (3000, 1, 1))
    cov[::37, 2, 2] = 1.0
    hit = emap.hit_cells([(xyz[:1500], cov[:1500], None), (xyz[1500:], cov[1500:], None)])
    before = emap.n.copy() + emap.outliers
    stats = emap.merge(xyz, cov=cov)
    assert hit.sum() == stats.cells_measured > 100
    assert np.array_equal(emap.n + emap.outliers != before, hit & (emap.n + emap.outliers != before))
