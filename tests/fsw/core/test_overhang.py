"""Overhang tests of the face map (fsw.core.map.overhang; docs/algorithm.md §8.1)."""

from __future__ import annotations

import math

import numpy as np

from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap
from fsw.core.map.face_map import FaceFrame, FaceMap, FaceMapConfig, hand_over_z
from fsw.core.map.overhang import FLAG_TESTS, facing_cones


def _frame() -> FaceFrame:
    a = math.radians(70.0)
    return FaceFrame.from_normal(np.zeros(3), np.array([0.0, -math.sin(a), math.cos(a)]))


def _view(face: FaceMap, rng: np.random.Generator, slope: float, eye_f: list[float]) -> None:
    """One view (camera ``eye_f``, face frame) of the face (w = 0, v in 0.3..1) and, over one row
    of cells (v in 0.2..0.3), a rock's side whose plane rises ``slope`` in w per metre of v:
    ``slope > 0`` faces up the dip and toward the face, ``slope < 0`` up the dip and out (a step
    down the face, one surface). The face below the rock is hidden from the camera."""
    n = 3000
    u = rng.uniform(0.0, 1.0, n)
    v = rng.uniform(0.2, 1.0, n)
    side = v < 0.3
    w = np.where(side, 0.3 + slope * (v - 0.25), 0.0) + rng.normal(0.0, 0.004, n)
    q = np.column_stack([u, v, w])
    cov = np.tile(np.eye(3)[None] * 1e-5, (n, 1, 1))
    f = face.frame
    face.merge_parts([(f.to_world(q), cov, None)], eye=f.to_world(np.array([eye_f]))[0])


def test_a_side_facing_the_face_is_an_overhang_and_a_step_is_not() -> None:
    """The rock's side that faces up the face and toward it, seen from above (a RECON-bot on the
    plateau, behind the plane), is where the normal passes from air into the rock: its cells
    hold two surfaces although no view saw the rock's outer side nor passed under it. A step
    down the face seen from the same place faces outward: one surface, no flag; the face
    around either is not flagged."""
    f = _frame()
    cfg = FaceMapConfig(cell_m=0.1)
    eye = [0.5, 3.0, 0.3]
    face = FaceMap(f, (0.0, 1.0), (0.0, 1.0), cfg)
    _view(face, np.random.default_rng(0), 3.0, eye)  # w = 0.3 + 3 (v - 0.25): rises up the dip
    assert face.overhang[2, :].all() and (face.facing[2, :] >= cfg.facing_min_points).all()
    assert (face.flagged_by[2, :] == FLAG_TESTS.index("facing")).all()
    assert face.overhang.sum() == face.grid.nx, face.overhang.astype(int)  # the face around: not flagged
    # the side's points are the inner side of the rock along the normal: kept out of the height;
    # the second surface is their mean, on the side (w 0.15..0.45; the points whose neighbours
    # straddle the side's ends fit no plane within the noise, so they are not spread evenly)
    assert np.allclose(face.second[2, :], 0.3, atol=0.1)
    assert np.allclose(face.map.z[6:, :], 0.0, atol=0.01)
    step = FaceMap(f, (0.0, 1.0), (0.0, 1.0), cfg)
    _view(step, np.random.default_rng(0), -3.0, [0.5, 3.0, 1.5])  # falls up the dip: faces outward
    assert not step.overhang.any(), step.overhang.astype(int)
    off = FaceMap(f, (0.0, 1.0), (0.0, 1.0), FaceMapConfig(cell_m=0.1, facing_max_points=0))
    _view(off, np.random.default_rng(0), 3.0, eye)  # the other tests alone miss it
    assert not off.overhang.any()


def test_facing_cones_fit_planes_in_the_noise_and_widen_where_there_is_none() -> None:
    """A tilted plane of points gives its normal within a narrow cone; a ball of points seldom a
    plane (a few neighbourhoods of its random points line up), a point with fewer than 8
    neighbours none."""
    rng = np.random.default_rng(2)
    p = np.column_stack([rng.uniform(0, 1, 4000), rng.uniform(0, 1, 4000), np.zeros(4000)])
    p[:, 2] = 0.5 * p[:, 0] + rng.normal(0, 0.002, 4000)
    noise = np.tile(np.eye(3)[None] * 0.002**2, (50, 1, 1))
    cone, ok = facing_cones(p, p[:50], noise, 0.08, 3.0)
    assert ok.all()
    true_n = np.array([-0.5, 0.0, 1.0]) / math.hypot(0.5, 1.0)
    assert np.allclose(np.abs(cone[:, 0] @ true_n), 1.0, atol=0.02)
    assert (np.abs(cone @ true_n) > np.cos(np.radians(10.0))).all()  # the whole cone near it
    blob = rng.normal(0, 0.05, (500, 3))
    inner = blob[np.argsort(np.linalg.norm(blob, axis=1))[:50]]  # their neighbours all round them
    _, ok = facing_cones(blob, inner, noise, 0.08, 3.0)
    assert ok.mean() < 0.1
    lone = np.array([[0.0, 0.0, 0.0], [5.0, 5.0, 5.0]])
    _, ok = facing_cones(np.vstack([lone, p]), lone, noise[:2], 0.08, 3.0)
    assert not ok.any()


def test_an_overhang_is_no_height_in_the_one_heightfield() -> None:
    """The planners' heightfield (``hand_over_z``) answers a flagged face cell as unknown: an
    overhang's held height may be either surface, not ground to stand on."""
    f = _frame()
    face = FaceMap(f, (-1.0, 1.0), (-1.0, 1.0), FaceMapConfig(cell_m=0.1, seam_m=0.1))
    face.map.z[:] = 0.05
    face.map.n[:] = 1
    face.map.var[:] = 1e-4
    gravity = ElevationMap(MapGrid(-1.0, -1.0, 0.05, 40, 40))
    own = face.face_owned(gravity.grid)
    assert np.isfinite(hand_over_z(gravity, face)[own]).all()
    face.overhang[8:12, 8:12] = True
    z = hand_over_z(gravity, face)
    X, Y = gravity.grid.centers()
    hole = np.isnan(z[own])
    assert hole.any() and (~hole).any()
    q = f.to_face(np.column_stack([X[own][~hole], Y[own][~hole], z[own][~hole]]))
    iy, ix, inside = face.grid.cell_index(q[:, 0], q[:, 1])
    assert inside.all() and not face.overhang[iy, ix].any()  # every answer stands on a single surface


def test_a_flag_spreads_to_the_cells_beside_it_that_show_some_facing_ground() -> None:
    """A rock's side that faces the face over two rows of cells, seen densely over the lower row
    and at two points per cell over the upper one (the view resolves its edge in part): the upper
    row's cells hold fewer facing points than the facing test needs, but those with one lie
    beside a flagged cell and are flagged too. The face beyond (no facing point) stays unflagged, and
    with the spread off the upper row is missed."""
    f = _frame()
    eye = [0.5, 3.0, 0.3]

    def view(cfg: FaceMapConfig) -> FaceMap:
        rng = np.random.default_rng(5)
        face = FaceMap(f, (0.0, 1.0), (0.0, 1.0), cfg)
        n = 2000
        u = rng.uniform(0.0, 1.0, n)
        v = np.where(np.arange(n) < 600, rng.uniform(0.2, 0.25, n), rng.uniform(0.3, 1.0, n))
        uc = np.repeat(np.arange(20) * 0.05 + 0.025, 2) + np.tile([-0.01, 0.01], 20)  # two per upper cell
        vc = np.tile([0.252, 0.256], 20)  # just past the dense part: their neighbours span the side
        u, v = np.concatenate([u, uc]), np.concatenate([v, vc])
        side = v < 0.3
        w = np.where(side, 0.3 + 1.0 * (v - 0.25), 0.0) + rng.normal(0.0, 0.002, len(u))
        q = np.column_stack([u, v, w])
        cov = np.tile(np.eye(3)[None] * 1e-5, (len(q), 1, 1))
        face.merge_parts([(f.to_world(q), cov, None)], eye=f.to_world(np.array([eye]))[0])
        return face

    cfg = FaceMapConfig(cell_m=0.05)
    face = view(cfg)
    lower, upper = face.overhang[4, 1:-1], face.overhang[5, 1:-1]  # the rows' inner cells
    assert lower.all() and (face.facing[4, 1:-1] >= cfg.facing_min_points).all()
    some = face.facing[5, 1:-1] >= 1  # the upper cells where a point's plane was fitted
    assert (face.facing[5, 1:-1] < cfg.facing_min_points).all() and some.sum() >= 5
    assert (upper == some).all(), face.overhang.astype(int)
    assert (face.flagged_by[5, 1:-1][upper] == FLAG_TESTS.index("beside_flag")).all()
    assert not face.overhang[6:, :].any()  # the face beyond: no facing ground, no flag
    off = view(FaceMapConfig(cell_m=0.05, facing_beside_points=0))
    assert off.overhang[4, 1:-1].all() and not off.overhang[5, :].any()


def _stereo_view(face: FaceMap, q: np.ndarray, eye: np.ndarray, rng: np.random.Generator,
                 depth_per_m2: float, lateral_m: float = 0.0015) -> None:
    """One view of the face-frame points ``q`` from ``eye`` (face frame) as stereo measures them:
    each point off along its sight line by ``depth_per_m2 r^2`` (one sigma, range ``r``) and
    across it by ``lateral_m``, with that covariance."""
    d = q - eye
    r = np.linalg.norm(d, axis=1, keepdims=True)
    s = d / r
    sd = depth_per_m2 * r[:, 0] ** 2
    a = np.cross(s, [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(s, a)
    n = len(q)
    pts = q + s * (rng.normal(0.0, 1.0, n) * sd)[:, None] + lateral_m * (
        a * rng.normal(0.0, 1.0, (n, 1)) + b * rng.normal(0.0, 1.0, (n, 1)))
    cov = (sd[:, None, None] ** 2 * np.einsum("ni,nj->nij", s, s)
           + lateral_m**2 * (np.einsum("ni,nj->nij", a, a) + np.einsum("ni,nj->nij", b, b)))
    f = face.frame
    face.merge_parts([(f.to_world(pts), f.R @ cov @ f.R.T, None)], eye=f.to_world(eye[None])[0])


def test_ground_facing_the_face_seen_through_depth_noise_is_counted_and_kept_out_of_the_height() -> None:
    """A rock's side facing the face (its normal 63 deg past the face plane), seen from the
    plateau through a stereo pair's depth noise (about 1 cm at 2 m, along the sight line): its
    local planes, fitted in that noise, face the face, so its cells are flagged by the facing
    test and its points held out of their heights as the second surface. An unweighted fit
    made the patch as thick as its depth noise and counted none of them."""
    f = FaceFrame.from_normal(np.zeros(3), np.array([0.0, -math.sin(math.radians(75.0)), math.cos(math.radians(75.0))]))
    rng = np.random.default_rng(0)
    cfg = FaceMapConfig(cell_m=0.06)
    face = FaceMap(f, (0.0, 1.2), (0.0, 1.2), cfg)
    n = 6000
    u, v = rng.uniform(0.3, 0.9, n), rng.uniform(0.5, 0.6, n)
    side = np.column_stack([u, v, 0.25 + 0.5 * (v - 0.5)])  # rises towards the camera: faces the face
    _stereo_view(face, side, np.array([0.6, 2.0, -0.4]), rng, 0.003)
    cells = face.overhang[8:10, 5:15]  # the side's cells, away from its ends
    assert cells.all() and (face.facing[8:10, 5:15] >= cfg.facing_min_points).all()
    assert np.isfinite(face.second[8:10, 5:15]).all()
    held = face.map.mapped[8:10, 5:15]
    assert not held.all(), "the side's points are the second surface, not the cells' height"


def test_a_plain_face_seen_through_heavy_depth_noise_shows_no_ground_facing_the_face() -> None:
    """A plane face, seen at grazing incidence from the plateau through heavy depth noise
    (1 cm at 1 m, 9 cm at 3 m, along the sight line): the noise smears the points along the
    sight lines, and no local plane may come out facing the face. None of its points counts as
    facing it and no cell is flagged (the unweighted fit counted some of the smear as facing
    the face)."""
    f = FaceFrame.from_normal(np.zeros(3), np.array([0.0, -math.sin(math.radians(75.0)), math.cos(math.radians(75.0))]))
    for seed in range(3):
        rng = np.random.default_rng(seed)
        face = FaceMap(f, (0.0, 1.2), (0.0, 1.2), FaceMapConfig(cell_m=0.06))
        n = 20000
        plane = np.column_stack([rng.uniform(0.0, 1.2, n), rng.uniform(0.0, 1.2, n), np.zeros(n)])
        _stereo_view(face, plane, np.array([0.6, 3.0, 0.3]), rng, 0.01)
        assert face.map.mapped.sum() > 300
        assert not face.facing.any(), face.facing
        assert not face.overhang.any(), face.overhang.astype(int)
