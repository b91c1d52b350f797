"""Occluding lips (fsw.core.stereo.occlusion): detection on a disparity step, and the guard that keeps a
horizontally uncertain view from placing plateau heights past its own lips."""

from __future__ import annotations

import numpy as np

from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap, FusionConfig
from fsw.core.stereo.occlusion import LipGuard, lip_pixels


def _ground_disparity(h: int = 120, w: int = 40) -> np.ndarray:
    """Ground seen obliquely: the disparity grows smoothly toward the bottom rows."""
    return np.tile(10.0 + 0.1 * np.arange(h)[:, None], (1, w))


def test_a_disparity_step_with_the_far_side_above_is_a_lip() -> None:
    d = _ground_disparity()
    d[:60] -= 6.0  # rows above 60: ground 6 px farther (behind a drop)
    d[58:62] = np.nan  # the matching windows straddling the jump give nothing
    v, u, vfar = lip_pixels(d, jump_px=1.0, rows=6)
    assert set(v.tolist()) == {62, 63}  # the first rows below the gap, within 6 rows of the far side
    assert set(vfar.tolist()) == {56, 57} and u.size == 2 * d.shape[1]


def test_smooth_ground_a_near_side_step_and_a_textureless_gap_are_not_lips() -> None:
    d = _ground_disparity()
    assert lip_pixels(d, 1.0, 6)[0].size == 0  # continuous ground
    up = _ground_disparity()
    up[:60] += 6.0  # the rows above are NEARER (a wall facing the camera): no occlusion behind
    assert lip_pixels(up, 1.0, 6)[0].size == 0
    gap = _ground_disparity()
    gap[:40] -= 3.0
    gap[40:70] = np.nan  # a 30-row textureless patch: not a lip, however the sides differ
    assert lip_pixels(gap, 1.0, 6)[0].size == 0


GRID = MapGrid(x0=-1.5, y0=-1.5, cell=0.03, nx=100, ny=100)


def _lip_view(shift_y: float, sigma_xy: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One view of a plateau (z = 0 for y > 0) above a drop whose face (0 < -y < 0.27 m) the
    camera cannot see; the lower ground (z = -1) is seen from y = -1.2 m on. The view's points
    are all displaced by ``shift_y`` (a pose error) and carry a horizontal sigma that covers it."""
    rng = np.random.default_rng(0)
    xs = rng.uniform(-1.0, 1.0, 20000)
    ys = np.concatenate([rng.uniform(0.0, 1.2, 12000), rng.uniform(-1.45, -1.2, 8000)])
    z = np.where(ys > 0, 0.0, -1.0) + rng.normal(0, 0.005, ys.size)
    xyz = np.column_stack([xs, ys + shift_y, z])
    cov = np.zeros((ys.size, 3, 3))
    cov[:, 0, 0] = cov[:, 1, 1] = sigma_xy**2
    cov[:, 2, 2] = 0.005**2
    lx = np.linspace(-1.0, 1.0, 200)
    near = np.column_stack([lx, np.full(200, shift_y), np.zeros(200)])  # the lip, as the view saw it
    far = np.column_stack([lx, np.full(200, -1.2 + shift_y), np.full(200, -1.0)])
    return xyz, cov, near, far


def _band_cells(emap: ElevationMap) -> int:
    """Mapped cells over the face (true height below -0.1 m, 0 < -y < 0.27) mapped above -0.1 m."""
    _, Y = GRID.centers()
    face = (Y < -0.015) & (Y > -0.27)
    return int(np.count_nonzero(emap.mapped & face & (emap.z > -0.1)))


def test_guard_keeps_a_displaced_view_off_the_occluded_face() -> None:
    xyz, cov, near, far = _lip_view(shift_y=-0.15, sigma_xy=0.1)
    plain = ElevationMap(GRID, FusionConfig())
    plain.merge(xyz, cov=cov)
    assert _band_cells(plain) > 200  # without the guard: the plateau height 15 cm past the lip
    guard = LipGuard(GRID, near, far, min_drop_m=0.1)
    keep = guard.clear(xyz, cov, 2.0)
    guarded = ElevationMap(GRID, FusionConfig())
    guarded.merge(xyz[keep], cov=cov[keep])
    assert _band_cells(guarded) == 0
    # what is withheld is within 2 sigma of the lip; the rest of the plateau is still mapped
    dy = np.abs(xyz[:, 1] - near[0, 1])
    assert np.all(dy[~keep] <= 0.2 + 1e-9) and np.all(keep[dy > 0.2 + 0.011])
    assert guarded.mapped.sum() > 0.75 * plain.mapped.sum()


def test_an_accurate_view_loses_only_points_at_its_lips() -> None:
    xyz, cov, near, far = _lip_view(shift_y=0.0, sigma_xy=0.01)
    keep = LipGuard(GRID, near, far, min_drop_m=0.1).clear(xyz, cov, 2.0)
    dy = np.abs(xyz[:, 1])
    assert np.all(dy[~keep] <= 0.02 + 1e-9)
    assert keep.mean() > 0.98


def test_a_small_step_is_not_a_drop_and_no_lips_keep_everything() -> None:
    xyz, cov, near, far = _lip_view(shift_y=-0.15, sigma_xy=0.1)
    far[:, 2] = -0.05  # a 5 cm step: below min_drop_m
    assert LipGuard(GRID, near, far, min_drop_m=0.1).clear(xyz, cov, 2.0).all()
    empty = np.zeros((0, 3))
    assert LipGuard(GRID, empty, empty, 0.1).clear(xyz, cov, 2.0).all()
    assert LipGuard(GRID, near, far, 0.1).clear(xyz, cov, 0.0).all()  # k = 0: guard off


def test_a_views_own_lip_withholds_only_what_it_can_hide_from_its_camera() -> None:
    """A view's own lip along y = 0 (the plateau, z = 0, drops to ground 1 m lower) and points of
    the face just past it, within the guard's reach: from the camera behind the lip, whose sight
    lines pass under it, they are withheld; from a camera beyond the lip looking back at the face,
    which no lip hides, they are kept; points at the lip itself are withheld from both."""
    lx = np.linspace(-1.0, 1.0, 200)
    near = np.column_stack([lx, np.zeros(200), np.zeros(200)])
    far = np.column_stack([lx, np.full(200, -1.2), np.full(200, -1.0)])
    guard = LipGuard(GRID, near, far, min_drop_m=0.1)
    face = np.column_stack([lx[50:150:10], np.full(10, -0.03), np.full(10, -0.25)])
    rim = np.column_stack([lx[50:150:10], np.full(10, 0.01), np.zeros(10)])
    xyz = np.concatenate([face, rim])
    cov = np.tile(np.eye(3) * 0.02**2, (xyz.shape[0], 1, 1))
    behind = guard.clear(xyz, cov, 2.0, eye=np.array([0.0, 3.0, 1.0]))
    beyond = guard.clear(xyz, cov, 2.0, eye=np.array([0.0, -0.4, 0.45]))
    assert not behind.any()
    assert beyond[:10].all() and not beyond[10:].any()
    assert not guard.clear(xyz, cov, 2.0).any()  # without the camera: every point near a lip
