"""Free space along stereo rays (``fsw.core.map.free_space``) and the face map's overhang flag from
it (docs/algorithm.md §8.1), on synthetic columns and rays (no rendering)."""

from __future__ import annotations

import math

import numpy as np

from fsw.core.geometry import MapGrid
from fsw.core.map.face_map import FaceFrame, FaceMap, FaceMapConfig
from fsw.core.map.free_space import air_under
from fsw.core.map.overhang import FLAG_TESTS

GRID = MapGrid(0.0, 0.0, 0.1, 10, 4)  # u 0..1, v 0..0.4


def _surface(z_roof: float) -> tuple[np.ndarray, np.ndarray]:
    """Every cell at w = 0 except column u in [0.4, 0.6) (cells 4, 5), a roof at ``z_roof``."""
    z = np.zeros(GRID.shape)
    z[:, 4:6] = z_roof
    return z, np.full(GRID.shape, 1e-4)


def _rays(w: float, n: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """``n`` rays along u at height ``w`` (from u = -0.5 to u = 0.95), spread over v."""
    v = np.linspace(0.05, 0.35, n)
    q = np.column_stack([np.full(n, 0.95), v, np.full(n, w)])
    return np.array([-0.5, 0.2, w]), q


def test_a_ray_under_a_roof_proves_air_under_it() -> None:
    z, var = _surface(0.5)
    eye, q = _rays(0.1)
    # the eye's v is one value: the rays fan out in v; each crosses the roof's columns below it
    rays, lowest = air_under(GRID, z, var, eye, q, np.full(len(q), 1e-4), np.full(len(q), 0.05), (-0.5, 1.5),
                             0.1, 3.0, 0.02)
    under = rays.reshape(GRID.shape)
    assert under[:, 4:6].sum() >= len(q) and under[:, :4].sum() == 0 and under[:, 6:].sum() == 0
    assert np.nanmin(lowest.reshape(GRID.shape)[:, 4:6][under[:, 4:6] > 0]) < 0.5 - 0.1
    # above the roof, or under it by less than the gap plus the margin: no evidence
    for w in (0.6, 0.45):
        rays, _ = air_under(GRID, z, var, *_rays(w), np.full(5, 1e-4), np.full(5, 0.05), (-0.5, 1.5), 0.1, 3.0, 0.02)
        assert rays.sum() == 0
    # a large variance of the cell (or of the ray) raises the margin past the roof
    rays, _ = air_under(GRID, z, np.full(GRID.shape, 0.04), eye, q, np.full(len(q), 1e-4), np.full(len(q), 0.05),
                        (-0.5, 1.5), 0.1, 3.0, 0.02)
    assert rays.sum() == 0


def test_the_ray_stops_short_of_its_point_and_counts_each_ray_once_per_cell() -> None:
    z, var = _surface(0.5)
    eye = np.array([-0.5, 0.2, 0.1])
    q = np.array([[0.5, 0.2, 0.1]])  # ends inside the roof's column (a point seen in it)
    r_far, _ = air_under(GRID, z, var, eye, q, np.full(1, 1e-4), np.full(1, 0.2), (-0.5, 1.5), 0.1, 3.0, 0.01)
    assert r_far.sum() == 0  # cut 0.2 m short: it never reaches the column
    r_near, _ = air_under(GRID, z, var, eye, q, np.full(1, 1e-4), np.full(1, 0.02), (-0.5, 1.5), 0.1, 3.0, 0.01)
    assert r_near.reshape(GRID.shape)[2, 4] == 1  # many samples in the cell, one ray


def test_bad_rays_are_ignored() -> None:
    z, var = _surface(0.5)
    eye = np.array([-0.5, 0.2, 0.1])
    q = np.array([[np.nan, 0.2, 0.1], [np.inf, 0.2, 0.1], [-0.5, 0.2, 0.1]])  # NaN, inf, zero length
    rays, lowest = air_under(GRID, z, var, eye, q, np.full(3, 1e-4), np.full(3, 0.02), (-0.5, 1.5), 0.1, 3.0, 0.02)
    assert rays.sum() == 0 and np.isinf(lowest).all()


def _frame() -> FaceFrame:
    a = math.radians(70.0)
    return FaceFrame.from_normal(np.zeros(3), np.array([0.0, -math.sin(a), math.cos(a)]))


def test_the_face_map_flags_a_roof_no_view_saw_under() -> None:
    """A roof (w = 0.4) over a face (w = 0): one view sees only the roof's top; another sees the
    face beyond the roof from the side, its rays passing under the roof. The roof's cells are
    flagged from the free space alone (no point under them); the face around is not."""
    f = _frame()
    cfg = FaceMapConfig(cell_m=0.1, air_min_rays=3)
    face = FaceMap(f, (0.0, 1.0), (0.0, 0.4), cfg)
    rng = np.random.default_rng(0)
    n = 4000
    u, v = rng.uniform(0.0, 1.0, n), rng.uniform(0.0, 0.4, n)
    roof = (u >= 0.4) & (u < 0.6)
    w = np.where(roof, 0.4, 0.0) + rng.normal(0, 0.003, n)
    cov = np.tile(np.eye(3)[None] * 1e-5, (n, 1, 1))
    eye_top = f.to_world(np.array([[0.5, 0.2, 50.0]]))[0]  # far out along the normal: nothing hidden
    st = face.merge_parts([(f.to_world(np.column_stack([u, v, w])), cov, None)], eye=eye_top)
    assert st.overhang_new == 0 and not face.overhang.any()
    # from the side, low: rays to the face beyond the roof (u > 0.6) pass under it
    side = ~roof & (u > 0.6)
    eye_side = f.to_world(np.array([[-1.0, 0.2, 0.15]]))[0]
    parts = [(f.to_world(np.column_stack([u[side], v[side], w[side]])), cov[side], None)]
    st = face.merge_parts(parts, eye=eye_side)
    assert face.overhang[:, 4:6].all() and st.air_new == face.overhang.sum() == 8
    assert (face.air[:, 4:6] >= 3).all() and (face.air_w[:, 4:6] < 0.4 - 0.1).all()
    assert (face.flagged_by[:, 4:6] == FLAG_TESTS.index("free_space")).all()
    assert np.allclose(face.map.z[:, 4:6], 0.4, atol=0.01)  # flagged, the roof still held


def test_a_surface_seen_from_below_is_flagged_and_a_step_is_not() -> None:
    """A roof rising toward the camera (w = 0.5 u), seen from under its tangent plane, is the lower
    side of an overhang: flagged. The same roof seen from above, and a step between two flat
    levels seen from above both, beyond the step (a central difference would tilt the cells on
    both sides of it toward the camera; the min-mod gradient tilts neither), are not."""
    f = _frame()
    # the underside test alone (the roof's lower side also faces the face: the facing test, which
    # runs first, would flag it by itself)
    cfg = FaceMapConfig(cell_m=0.1, air_max_rays=5000, air_min_rays=1000, facing_max_points=0)
    rng = np.random.default_rng(1)
    n = 2000
    u, v = rng.uniform(0.0, 1.0, n), rng.uniform(0.0, 0.4, n)
    cov = np.tile(np.eye(3)[None] * 1e-6, (n, 1, 1))
    for w, eye, flagged in ((0.5 * u, [3.0, 0.2, 0.0], True), (0.5 * u, [-1.0, 0.2, 2.0], False),
                            (np.where(u < 0.5, 0.0, 0.3), [2.0, 0.2, 1.0], False)):
        face = FaceMap(f, (0.0, 1.0), (0.0, 0.4), cfg)
        xyz = f.to_world(np.column_stack([u, v, w + rng.normal(0, 0.001, n)]))
        face.merge_parts([(xyz, cov, None)], eye=f.to_world(np.array([eye]))[0])
        # the grid's first and last columns have no slope (one neighbour): only the others tilt
        assert face.overhang[:, 1:-1].all() if flagged else not face.overhang.any(), (eye, face.overhang.sum())
        assert (face.flagged_by[face.overhang] == FLAG_TESTS.index("underside")).all()
