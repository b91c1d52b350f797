"""The face map's variance at grazing incidence (docs/algorithm.md §8.1, "The relief the view
cannot resolve"): a view whose points' error lies along the face blurs the relief, and the
variances it gives its cells must still cover their error; a second agent's better view of a
cell must not leave the fused cell worse than that view alone."""

from __future__ import annotations

import numpy as np
import pytest

from fsw.core.geometry import MapGrid
from fsw.core.map.face_elevation import FaceElevation, relief_variance, step_heights
from fsw.core.map.face_map import FaceFrame, FaceMap, FaceMapConfig, run_merge, window_span

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


def test_the_steps_term_is_zero_on_a_plane_and_a_steps_height_beside_a_step() -> None:
    """The steps beside a cell are measured from its tangent plane (min-mod gradient): a tilted
    plane adds nothing to the slope term, a 0.2 m step gives the cells within two cells of it
    (on either side) its height, up from below and down from above, and the cells farther none."""
    g = MapGrid(0.0, 0.0, CELL, 8, 8)
    X, Y = g.centers()
    cells = np.arange(64)
    tilt = 0.5 * Y.reshape(-1) + 0.3 * X.reshape(-1)
    assert np.allclose(relief_variance(g, cells, tilt, 2), relief_variance(g, cells, tilt, 0))
    z = np.where(np.arange(16) >= 8, 0.2, 0.0)[:, None] * np.ones((1, 8))
    up, down = step_heights(z, 2)
    assert np.allclose(up[6:8], 0.2) and np.allclose(down[8:10], 0.2)
    assert np.allclose(up[8:], 0.0) and np.allclose(down[:8], 0.0)
    assert np.allclose(up[:6], 0.0) and np.allclose(down[10:], 0.0)


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


def test_the_window_span_grows_as_the_sight_line_grazes_the_face() -> None:
    """``window_rad r / cos t``: a 5 px window of a 686 px focal length at 2.4 m spans 0.1 m of
    face at 80 deg incidence, 0.018 m head-on; a sight line along the plane spans all of it."""
    frame = FaceFrame.from_normal(np.zeros(3), np.array([0.0, -np.sin(np.radians(75)), np.cos(np.radians(75))]))
    w = 5.0 / 686.0
    p = np.zeros((1, 3))
    for t_deg, span in ((80.0, 0.1007), (0.0, 0.0175)):
        t = np.radians(t_deg)
        eye = 2.4 * (np.cos(t) * frame.normal + np.sin(t) * frame.R[:, 1])
        assert window_span(frame, eye, p, w)[0] == pytest.approx(span, rel=1e-2)
    assert window_span(frame, 2.4 * frame.R[:, 1], p, w)[0] > 1e3


def test_a_grazing_view_does_not_fuse_the_cells_it_cannot_resolve() -> None:
    """A view at 86 deg from the face normal, 3 m away, whose points sit 4 cm out of the face
    (the window mixes the relief turned towards it), and one at 40 deg, 1 m away, on the face:
    the first spans 0.3 m of face per window, five 6 cm cells, and is left out of the heights
    (the cells hold the second view, on the true surface); without the limit its points are
    fused and about half the cells (those where the gate swapped in its equally tight
    measurement) sit out of the face, outside their 2 sigma (the steps' term off: the grazing
    view's noisy cell means would read as steps and loosen its cells)."""
    a = np.radians(75.0)
    frame = FaceFrame.from_normal(np.zeros(3), np.array([0.0, -np.sin(a), np.cos(a)]))
    cfg = FaceMapConfig(cell_m=CELL, air_max_rays=0, facing_max_points=0, resolve_cells=1.0, step_cells=0)
    rng = np.random.default_rng(5)
    q = np.column_stack([rng.uniform(0.1, 1.1, 4000), rng.uniform(0.1, 1.1, 4000), np.zeros(4000)])
    cov = np.tile(np.diag([1e-4, 1e-4, 0.005**2]), (len(q), 1, 1))

    def eye_at(t_deg: float, r: float) -> np.ndarray:
        t = np.radians(t_deg)
        at = frame.to_world(np.array([[0.6, 0.6, 0.0]]))[0]
        return at + r * (np.cos(t) * frame.normal + np.sin(t) * frame.R[:, 1])

    window = 5.0 / 686.0
    grazing = frame.to_world(q + [0.0, 0.0, 0.04] + rng.normal(0, 0.005, q.shape) * [0, 0, 1])
    near = frame.to_world(q + rng.normal(0, 0.005, q.shape) * [0, 0, 1])
    out = {}
    for limit in (True, False):
        fm = FaceMap(frame, (0.0, 1.2), (0.0, 1.2), cfg)
        wr = window if limit else None
        st = fm.merge_parts([(grazing, cov, None)], eye=eye_at(86.0, 3.0), window_rad=wr)
        assert st.grazing == (len(q) if limit else 0)
        assert (fm.map.mapped.sum() == 0) == limit
        st = fm.merge_parts([(near, cov, None)], eye=eye_at(40.0, 1.0), window_rad=wr)
        assert st.grazing == 0
        m = fm.map.mapped
        out[limit] = float(np.mean(np.abs(fm.map.z[m]) <= 2 * np.sqrt(fm.map.var[m])))
    assert out[True] >= 0.9 and out[False] < 0.6


def test_the_matchers_window_angle_is_its_block_over_the_focal_length() -> None:
    """The RECON-bot's pair (640 px over 50 deg, f = 686 px) and a 5 px block: 7.3 mrad; a
    7 px block on the Cliff-bot's (320 px over 60 deg, f = 277 px): 25 mrad."""
    from fsw.core.geometry import CameraConfig
    from fsw.core.stereo.stereo import StereoConfig, StereoMatcher

    assert StereoMatcher(StereoConfig(), CameraConfig()).window_rad == pytest.approx(5 / 686.2, rel=1e-3)
    small = CameraConfig(width_px=320, height_px=240, hfov_deg=60.0, baseline_m=0.07)
    assert StereoMatcher(StereoConfig(block_size_px=7), small).window_rad == pytest.approx(7 / 277.1, rel=1e-3)


def test_a_grazing_view_beside_a_step_keeps_those_cells_within_two_sigma() -> None:
    """A face with a 0.2 m step out of it across the dip, seen at grazing incidence: in the two
    rows of cells below the step the view sees the step's side and top, not their own ground
    (each cell's points lie at a share of the step's height drawn per cell, uniform). With the
    steps' term (``step_cells = 2``) at least 85 % of those cells hold their true height within
    2 sigma (the ramp such cells make up to the step is read partly as the ground's slope); on
    the slope term alone under 60 % do. Cells more than two cells from the step keep about the
    sigma they had without the term (their neighbours' means differ by their noise only, which
    the term counts as relief: a median 20 % more here, at most twice)."""
    rng = np.random.default_rng(7)
    n, per_cell, step_row, height = 20, 20, 10, 0.2
    u = rng.uniform(0, n * CELL, n * n * per_cell)
    v = rng.uniform(0, n * CELL, n * n * per_cell)
    row, col = (v // CELL).astype(int), (u // CELL).astype(int)
    share = rng.uniform(0.0, 1.0, (n, n))
    w = np.where(row >= step_row, height, 0.0)
    beside = (row == step_row - 1) | (row == step_row - 2)
    w = np.where(beside, height * share[row, col], w) + rng.normal(0, 0.003, len(u))
    cov = np.tile(np.diag([1e-6, 1e-4, 0.003**2]), (len(u), 1, 1))
    xyz = np.column_stack([u, v, w])
    maps = {}
    for cells in (2, 0):
        fm = FaceElevation(MapGrid(0.0, 0.0, CELL, n, n), step_cells=cells)
        run_merge(fm, [(xyz, cov, None)], None)
        maps[cells] = fm
    truth = np.where(np.arange(n) >= step_row, height, 0.0)[:, None]
    rows = slice(step_row - 2, step_row)
    for cells, lo, hi in ((2, 0.85, 1.0), (0, 0.0, 0.6)):
        e = (maps[cells].z - truth)[rows]
        rate = float(np.mean(np.abs(e) <= 2 * np.sqrt(maps[cells].var[rows])))
        assert lo <= rate <= hi, (cells, rate)
    far = slice(0, step_row - 5)
    grow = np.sqrt(maps[2].var[far] / maps[0].var[far])
    assert np.median(grow) <= 1.25 and grow.max() <= 2.0, (np.median(grow), grow.max())


def test_a_cell_beside_ground_the_view_did_not_see_keeps_its_error_within_two_sigma() -> None:
    """A staircase of 0.15 m steps every 5 rows, seen by one view: on the left half in full, on
    the right half at grazing incidence, where the two rows below each step's edge lie in its
    shadow (no point) and the three rows it sees of each tread all get the step's mixed depth
    (a share of the rise, one per tread): flat, at the wrong height, with no step in the view's
    own cell means. With ``hidden_relief`` the tread rows beside the shadow gain the view's mean
    steps' variance (measured on the left half) and at least 90 % of their cells hold their true
    height within 2 sigma; without it under 30 % do. Cells whose neighbours the view all saw
    keep their variance."""
    from fsw.core.map.elevation_map import FusionConfig

    rng = np.random.default_rng(11)
    n, per_cell, rise = 30, 20, 0.15
    rows = np.arange(n)
    truth = rise * (rows // 5)
    shadow = rows % 5 >= 3
    u = rng.uniform(0, n * CELL, n * n * per_cell)
    v = rng.uniform(0, n * CELL, n * n * per_cell)
    row, col = (v // CELL).astype(int), (u // CELL).astype(int)
    right = col >= n // 2
    keep = ~(right & shadow[row])
    u, v, row, col, right = u[keep], v[keep], row[keep], col[keep], right[keep]
    share = rng.uniform(0.2, 1.0, n // 5)  # per tread
    w = truth[row] + np.where(right, rise * share[row // 5], 0.0) + rng.normal(0, 0.003, len(u))
    cov = np.tile(np.diag([1e-6, 1e-4, 0.003**2]), (len(u), 1, 1))
    xyz = np.column_stack([u, v, w])
    maps = {}
    for hidden in (True, False):
        fm = FaceElevation(MapGrid(0.0, 0.0, CELL, n, n), FusionConfig(hidden_relief=hidden), step_cells=2)
        run_merge(fm, [(xyz.copy(), cov.copy(), None)], None)
        maps[hidden] = fm
    beside = ((rows % 5 == 0) & (rows > 0)) | (rows % 5 == 2)
    cols = slice(n // 2 + 2, n)  # clear of the left half's true cells
    for hidden, lo, hi in ((True, 0.9, 1.0), (False, 0.0, 0.3)):
        e = maps[hidden].z[beside, cols] - truth[beside][:, None]
        rate = float(np.mean(np.abs(e) <= 2 * np.sqrt(maps[hidden].var[beside, cols])))
        assert lo <= rate <= hi, (hidden, rate)
    seen = slice(3, n // 2 - 3)  # the left half, away from the grid's edges and the right half
    assert np.allclose(maps[True].var[3:-3, seen], maps[False].var[3:-3, seen])


def test_a_rock_top_seen_alone_is_not_taken_for_the_face_beside_it() -> None:
    """A view from the plateau sees only a rock's top standing 0.4 m out of the face (a 4 x 4
    patch of cells, flat): the rock overhangs the face around it, so under the patch's outer
    ring the face itself lies near the plane. The view resolves no neighbourhood of its own (no
    relief to measure), yet those cells stand 0.4 m out of the fitted plane beside ground it did
    not see: with ``hidden_relief`` every ring cell holds the face's height within 2 sigma;
    without it none does."""
    from fsw.core.map.elevation_map import FusionConfig

    rng = np.random.default_rng(5)
    n, top = 15, 0.4
    u = rng.uniform(5 * CELL, 9 * CELL, 2000)
    v = rng.uniform(5 * CELL, 9 * CELL, 2000)
    xyz = np.column_stack([u, v, top + rng.normal(0, 0.005, len(u))])
    cov = np.tile(np.diag([1e-4, 1e-4, 0.005**2]), (len(u), 1, 1))
    truth = np.zeros((n, n))
    truth[6:8, 6:8] = top  # the rock's body; the ring around it is its overhanging rim
    ring = np.zeros((n, n), bool)
    ring[5:9, 5:9] = True
    ring[6:8, 6:8] = False
    for hidden, want in ((True, 1.0), (False, 0.0)):
        fm = FaceElevation(MapGrid(0.0, 0.0, CELL, n, n), FusionConfig(hidden_relief=hidden), step_cells=2)
        run_merge(fm, [(xyz.copy(), cov.copy(), None)], None)
        e = fm.z[ring] - truth[ring]
        assert float(np.mean(np.abs(e) <= 2 * np.sqrt(fm.var[ring]))) == want, hidden


def test_only_the_ground_a_view_looked_at_and_missed_counts_as_hidden() -> None:
    """A view that put points on the face's square ``[0.3, 0.6]^2`` from a camera 1.5 m out in
    front of it looked at that square (and up to its range) and at nothing far outside it: the
    ring beyond the square is out of the view (its image's edge), not hidden. A patch the view
    measured inside ground it looked at is beside hidden ground; the same patch with nothing
    looked at around it is not."""
    from fsw.core.map.face_elevation import hidden_relief
    from fsw.core.map.face_map import in_view

    frame = FaceFrame.from_normal(np.zeros(3), np.array([0.0, -np.sin(1.2), np.cos(1.2)]))
    face = FaceMap(frame, (0.0, 0.9), (0.0, 0.9), FaceMapConfig(cell_m=CELL))
    rng = np.random.default_rng(2)
    q = np.column_stack([rng.uniform(0.3, 0.6, 3000), rng.uniform(0.3, 0.6, 3000), np.zeros(3000)])
    eye = frame.to_world(np.array([[0.45, 0.45, 1.5]]))[0]
    looked = in_view(face, eye, frame.to_world(q))
    assert (in_view(face, eye, frame.to_world(q), max_range_m=5.0) == looked).all()
    assert not in_view(face, eye, frame.to_world(q), max_range_m=1.0).any()  # the face lies 1.5 m off
    g = face.grid
    X, Y = g.centers()
    inner = (X > 0.33) & (X < 0.57) & (Y > 0.33) & (Y < 0.57)
    outer = (X < 0.2) | (X > 0.7) | (Y < 0.2) | (Y > 0.7)
    assert looked[inner].all() and not looked[outer].any()
    z = np.full(g.shape, np.nan)
    z[6:9, 6:9] = 0.0  # a patch the view measured, inside the square it looked at
    beside, _ = hidden_relief(z, 2, looked)
    assert beside[6:9, 6:9].sum() == 8 and not beside[7, 7]
    beside, _ = hidden_relief(z, 2, np.isfinite(z))
    assert not beside.any()


def step_face(n: int = 20, step_row: int = 10, height: float = 0.15) -> tuple[MapGrid, np.ndarray]:
    """A view's cell means on a face with a step ``height`` out of it across the dip, from
    ``step_row`` up (face frame, 6 cm cells)."""
    g = MapGrid(0.0, 0.0, CELL, n, n)
    return g, np.where(np.arange(n) >= step_row, height, 0.0)[:, None] * np.ones((1, n))


def test_a_step_reaches_a_cell_through_its_shadow_or_the_matching_windows() -> None:
    """The steps' term of the cells below a 0.15 m step, by where the camera stands (docs/
    algorithm.md §8.1). Seen from the Cliff-bot's head 0.45 m off the face and below the step
    (the step rises beyond the cells, turned to the camera; its 25 mrad windows span 1.4 cm of
    face there), the step casts no shadow on them and its windows reach one cell in: the row
    next to the step gains part of the step's variance, the row beyond it none. Seen from
    above the step, those rows lie in its shadow, and seen at grazing incidence from 3.6 m (the
    RECON-bot's 7 mrad windows span 15 cm of face) the windows reach both rows: either way they
    gain the step's whole variance, as they do with no camera known."""
    g, z = step_face()
    cells = np.arange(g.nx * g.ny)
    zm = z.reshape(-1)
    full = 0.15**2 / 3.0
    extra = {}
    for name, eye, window in (("below", (0.6, 0.3, 0.45), 0.025), ("above", (0.6, 1.5, 0.45), 0.025),
                              ("grazing", (0.6, -3.0, 0.6), 0.0073), ("unknown", None, None)):
        steps = relief_variance(g, cells, zm, 2, None if eye is None else np.array(eye), window_rad=window)
        extra[name] = (steps - relief_variance(g, cells, zm, 0)).reshape(g.shape)[:, 8:12]
    assert np.allclose(extra["below"][8], 0.0)  # two rows below the step: beyond the windows' reach
    assert 0.2 * full < extra["below"][9].min() and extra["below"][9].max() < 0.8 * full
    for name in ("above", "grazing", "unknown"):
        assert np.allclose(extra[name][8:10], full), name


def test_a_close_view_beside_a_step_is_not_outweighed_by_a_grazing_one() -> None:
    """Two agents' views of a face with a 0.15 m step: the Cliff-bot's from 0.45 m off the face
    below the step, whose points lie on the true surface (5 mm noise, its pose 2 cm), and the
    RECON-bot's at grazing incidence from above, whose points on the two rows below the step
    (the step's shadow) hold the step's mixed depth, a share of its height per cell. In the row
    two cells below the step the fused cells are within 5 mm of the Cliff-bot's alone (the
    grazing view's weight there is its honest few per cent), and every map's cells there hold
    their error within 2 sigma. With the step's variance given in full to every cell within two
    of it, the close view's cells there weigh no more than the grazing view's and the fused row
    sits centimetres out."""
    a = np.radians(75.0)
    frame = FaceFrame.from_normal(np.zeros(3), np.array([0.0, -np.sin(a), np.cos(a)]))
    cfg = FaceMapConfig(cell_m=CELL, air_max_rays=0, facing_max_points=0)
    rng = np.random.default_rng(13)
    n, step_row, height = 20, 10, 0.15
    m = 20 * n * n
    u, v = rng.uniform(0, n * CELL, m), rng.uniform(0, n * CELL, m)
    row = (v // CELL).astype(int)
    truth = np.where(row >= step_row, height, 0.0)
    pose = np.array([0.0, 0.0, 0.02 * rng.standard_normal()])
    close = np.column_stack([u, v, truth + rng.normal(0, 0.005, m)]) + pose
    share = rng.uniform(0.0, 1.0, (n, n))
    shadow = (row == step_row - 1) | (row == step_row - 2)
    far_w = np.where(shadow, height * share[row, (u // CELL).astype(int)], truth) + rng.normal(0, 0.005, m)
    far = np.column_stack([u, v, far_w])
    pose_cov = np.tile(np.diag([0.02**2] * 3), (m, 1, 1))  # the Cliff-bot's pose: common to its view
    cov_close = pose_cov + np.diag([1e-6, 1e-6, 0.005**2])
    cov_far = np.tile(np.diag([1e-4, 0.03**2, 0.005**2]), (m, 1, 1))
    maps = {name: FaceMap(frame, (0.0, n * CELL), (0.0, n * CELL), cfg) for name in ("cliff", "recon", "fused")}

    def world(cov: np.ndarray) -> np.ndarray:
        return np.asarray(np.einsum("ij,njk,lk->nil", frame.R, cov, frame.R))

    views = {"cliff": ((frame.to_world(close), world(cov_close), world(pose_cov)), (0.6, 0.3, 0.45), 0.025),
             "recon": ((frame.to_world(far), world(cov_far), None), (0.6, 4.6, 0.9), 0.0073)}
    for agent in ("recon", "cliff"):
        part, eye, window = views[agent]
        for name in (agent, "fused"):
            maps[name].merge_parts([part], eye=frame.to_world(np.array([eye]))[0], window_rad=window)
    r = step_row - 2
    err = {k: fm.map.z[r, 2:-2] for k, fm in maps.items()}
    rms = {k: float(np.sqrt(np.mean(e * e))) for k, e in err.items()}
    assert rms["fused"] <= rms["cliff"] + 0.005, rms
    for k, fm in maps.items():
        assert np.mean(np.abs(err[k]) <= 2 * np.sqrt(fm.map.var[r, 2:-2])) >= 0.9, k
