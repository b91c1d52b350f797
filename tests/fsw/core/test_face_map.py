"""The face map (``fsw.core.map.face_map``, docs/algorithm.md §8.1) and the team mask
(``fsw.core.map.body_mask``), on synthetic faces and points (no rendering)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fsw.core.codec.mapcodec import decode_map, encode_map
from fsw.core.geometry import MapGrid
from fsw.core.map.body_mask import BodyBox, MaskConfig, TeamGeometry, TetherLine, team_mask
from fsw.core.map.elevation_map import ElevationMap
from fsw.core.map.face_map import FaceFrame, FaceMap, FaceMapConfig, fit_face_map, hand_over_z, split_parts
from fsw.core.map.face_plane import equal_memory_cell, face_band, fit_face_plane
from fsw.core.map.overhang import FLAG_TESTS

SLOPE = 70.0


def _face_frame() -> FaceFrame:
    a = math.radians(SLOPE)
    return FaceFrame.from_normal(np.array([0.0, -1.0, -1.5]), np.array([0.0, -math.sin(a), math.cos(a)]))


def _cliff_map(rng: np.random.Generator) -> ElevationMap:
    """A gravity map of a plateau (y > 0), a 70 deg face 3 m high, a floor with steep-sided rocks."""
    grid = MapGrid(-2.0, -4.0, 0.04, 100, 125)
    X, Y = grid.centers()
    run = 3.0 / math.tan(math.radians(SLOPE))
    z = np.where(Y > 0, 0.0, np.where(-run < Y, Y * math.tan(math.radians(SLOPE)), -3.0))
    for _ in range(12):  # boxes on the floor: steep sides facing every way
        cx, cy = rng.uniform(-1.8, 1.8), rng.uniform(-3.8, -run - 0.3)
        z = np.where((np.abs(X - cx) < 0.12) & (np.abs(Y - cy) < 0.12), z + 0.3, z)
    m = ElevationMap(grid)
    m.z = z + rng.normal(0, 0.01, z.shape)
    m.n[:] = 1
    m.var[:] = 1e-4
    return m


def test_frame_round_trip_and_axes() -> None:
    f = _face_frame()
    assert f.slope_deg == pytest.approx(SLOPE)
    assert np.allclose(f.R.T @ f.R, np.eye(3)) and np.linalg.det(f.R) == pytest.approx(1.0)
    assert abs(f.R[2, 0]) < 1e-12  # e_u horizontal
    assert f.normal[2] > 0 and f.normal[1] < 0  # out of the face (toward -y) and up
    p = np.random.default_rng(0).normal(size=(20, 3))
    assert np.allclose(f.to_world(f.to_face(p)), p)
    cov = np.stack([np.diag([1.0, 2.0, 3.0])] * 2)
    cf = f.cov_to_face(cov)
    assert np.allclose(cf[0], f.R.T @ cov[0] @ f.R)
    with pytest.raises(ValueError, match="neither vertical nor horizontal"):
        FaceFrame.from_normal(np.zeros(3), np.array([0.0, 0.0, 1.0]))


def test_fit_finds_the_face_among_rocks() -> None:
    m = _cliff_map(np.random.default_rng(1))
    f = fit_face_plane(m)
    assert f.slope_deg == pytest.approx(SLOPE, abs=2.0)
    assert f.normal[1] < -0.8  # facing the open side
    u, v = face_band(m, f)
    a = math.radians(SLOPE)
    assert 0.7 * 3.0 / math.sin(a) < v[1] - v[0] <= 3.0 / math.sin(a) + 0.1
    empty = ElevationMap(m.grid)
    with pytest.raises(ValueError, match="no face"):
        fit_face_plane(empty)
    # the face map on it: that plane and band, cells of equal memory, the rest of its settings as given
    face = fit_face_map(m, cfg=FaceMapConfig(seam_m=0.2))
    assert np.allclose(face.frame.R, f.R)
    for got, want in ((face.u_range, u), (face.v_range, v)):  # the band, in whole cells
        assert got[0] == pytest.approx(want[0]) and want[1] <= got[1] < want[1] + face.cfg.cell_m
    assert face.cfg.cell_m == pytest.approx(equal_memory_cell(m.grid.cell, f.slope_deg)) and face.cfg.seam_m == 0.2
    assert not face.map.mapped.any()
    with pytest.raises(ValueError, match="no face"):
        fit_face_map(empty)


def _points_on(face: FaceMap, u: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
    return face.frame.to_world(np.column_stack([u, v, w]))


def test_fusion_in_the_face_frame_and_the_codec() -> None:
    rng = np.random.default_rng(2)
    face = FaceMap(_face_frame(), (-1.0, 1.0), (-1.0, 1.0), FaceMapConfig(cell_m=0.1))
    n = 40000
    u, v = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
    w = 0.05 + 0.1 * u + rng.normal(0, 0.005, n)
    xyz = _points_on(face, u, v, w)
    cov = np.tile(np.diag([1e-4, 1e-4, 1e-4])[None], (n, 1, 1))
    st = face.merge_parts([(xyz, cov, None)])
    assert st.merge.cells_measured == face.grid.nx * face.grid.ny and st.overhang_new == 0
    X, Y = face.grid.centers()
    truth = 0.05 + 0.1 * X
    assert np.abs(face.map.z - truth).max() < 0.01
    assert (face.map.var < 1e-3).all() and face.map.mapped.all()
    # it is a grid with its own frame: the codec takes it as it is
    enc = encode_map(face.map.z, cell_m=face.grid.cell, wheel_diameter_m=0.12)
    dec = decode_map(enc.data)
    assert np.abs(dec.z - face.map.z).max() <= 0.12 + 1e-6


def test_an_overhang_is_flagged_not_averaged() -> None:
    face = FaceMap(_face_frame(), (0.0, 0.4), (0.0, 0.4), FaceMapConfig(cell_m=0.1, overhang_gap_m=0.1))
    rng = np.random.default_rng(3)
    k = 50
    # cell (0, 0): two surfaces over one spot (w 0 and 0.3); cell (0, 2): a step (two levels side by side)
    u = np.concatenate([rng.uniform(0.0, 0.05, 2 * k), rng.uniform(0.2, 0.25, k), rng.uniform(0.25, 0.3, k)])
    v = np.concatenate([rng.uniform(0.0, 0.05, 2 * k), rng.uniform(0.0, 0.1, 2 * k)])
    w = np.concatenate([np.zeros(k), np.full(k, 0.3), np.zeros(k), np.full(k, 0.3)]) + rng.normal(0, 0.003, 4 * k)
    cov = np.tile(np.eye(3)[None] * 1e-5, (4 * k, 1, 1))
    st = face.merge_parts([(_points_on(face, u, v, w), cov, None)])
    assert face.overhang[0, 0] and not face.overhang[0, 2]
    assert st.overhang_new == 1 and st.second_points == k
    assert face.map.z[0, 0] == pytest.approx(0.3, abs=0.01)  # the outer surface stays
    assert face.second[0, 0] == pytest.approx(0.0, abs=0.01)
    # a later view that sees the other surface of a mapped cell: flagged, not averaged
    u2, v2 = rng.uniform(0.3, 0.4, k), rng.uniform(0.3, 0.4, k)
    face.merge_parts([(_points_on(face, u2, v2, np.full(k, 0.0)), cov[:k], None)])
    z_before = face.map.z[3, 3]
    st = face.merge_parts([(_points_on(face, u2, v2, np.full(k, -0.4)), cov[:k], None)])
    assert face.overhang[3, 3] and st.overhang_new == 1 and face.map.z[3, 3] == z_before
    assert st.second_points == k
    assert face.second[3, 3] == pytest.approx(-0.4, abs=1e-6)
    # each flag says which test set it: two surfaces within a view, then across views
    assert face.flagged_by[0, 0] == FLAG_TESTS.index("within_view")
    assert face.flagged_by[3, 3] == FLAG_TESTS.index("across_views")
    assert (face.flagged_by[~face.overhang] == 0).all()


def test_hand_over_routes_and_answers_across_the_seam() -> None:
    f = _face_frame()
    face = FaceMap(f, (-1.0, 1.0), (-1.0, 1.0), FaceMapConfig(cell_m=0.1, seam_m=0.2, slab_out_m=0.5, slab_in_m=0.3))
    q = np.array([[0.0, 0.0, 0.0], [0.0, 0.9, 0.0], [0.0, 1.5, 0.0], [0.0, 0.0, 0.8], [1.5, 0.0, 0.0],
                  [0.0, 0.0, -0.4]])
    to_face, to_grav = face.routes(f.to_world(q))
    assert to_face.tolist() == [True, True, False, False, False, False]
    assert to_grav.tolist() == [False, True, True, True, True, True]  # the seam strip feeds both
    parts = [(f.to_world(q), np.tile(np.eye(3)[None] * 1e-4, (6, 1, 1)), None)]
    pf, pg = split_parts(parts, face)
    assert len(pf[0][0]) == 2 and len(pg[0][0]) == 5
    face.map.z[:] = 0.05
    face.map.n[:] = 1
    gravity = ElevationMap(MapGrid(-1.0, -2.5, 0.05, 40, 50))
    gravity.z[:] = -7.0
    own = face.face_owned(gravity.grid)
    assert own.any() and not own.all()
    z = hand_over_z(gravity, face)
    X, Y = gravity.grid.centers()
    assert np.allclose(z[own], f.plane_z(X[own], Y[own]) + 0.05 / f.normal[2])
    assert (z[~own] == -7.0).all()


def test_team_mask_boxes_and_tethers() -> None:
    box = BodyBox(np.array([0.0, 0.0, 0.2]), np.eye(3), np.array([0.3, 0.2, 0.2]))
    line = TetherLine(np.array([[0.0, 2.0, 0.3], [0.0, 0.2, 0.3]]), 0.006)
    team = TeamGeometry((box,), (line,))
    p = np.array([[0.0, 0.0, 0.35], [0.32, 0.0, 0.2], [0.0, 1.0, 0.32], [0.0, 1.0, 0.45], [1.0, 1.0, 0.3]])
    assert team_mask(p, None, team, MaskConfig(margin_m=0.04)).tolist() == [True, True, True, False, False]
    cov = np.tile(np.eye(3)[None] * 0.05**2, (5, 1, 1))  # 5 cm points: 3 sigma grows the shapes by 15 cm
    assert team_mask(p, cov, team).tolist() == [True, True, True, True, False]
    # seen past a shape: a ground point behind the tether or the box, from a camera at eye
    eye = np.array([1.0, 1.0, 2.0])
    ground = np.array([[-0.6, -0.3, -0.3], [-0.353, 1.0, -0.3], [1.5, 1.0, 0.0]])
    # the first is behind the box, the second's sight line crosses the tether, the third is clear
    got = team_mask(ground, None, team, MaskConfig(margin_m=0.04), eye=eye)
    assert got.tolist() == [True, True, False]
    only_tether = team_mask(ground, None, TeamGeometry((), (line,)), MaskConfig(margin_m=0.04), eye=eye)
    assert only_tether.tolist() == [False, True, False]
    assert not team_mask(ground, None, team, MaskConfig(margin_m=0.04)).any()
    inside = np.array([0.0, 0.0, 0.3])  # a camera on the box: its own volume only
    assert team_mask(ground[:1], None, TeamGeometry((box,), ()), eye=inside).tolist() == [False]
    with pytest.raises(ValueError, match="two points"):
        team_mask(p, None, TeamGeometry((), (TetherLine(np.zeros((1, 3)), 0.01),)))


def test_the_pipeline_routes_a_view_between_the_grids() -> None:
    """``SensingPipeline.fuse_steps`` with a face map: the face's points go to the face map, the
    rest (and the seam strips) to the gravity grid."""
    from fsw.core.geometry import CameraPose
    from fsw.core.pipeline import RegisteredPose, SensingPipeline
    from fsw.core.registration.registration import Registration
    from fsw.core.steps import run_to_end
    from fsw.settings import load_settings

    cfg = load_settings(check_calibration=False)
    pipe = SensingPipeline(cfg, None, emap=ElevationMap(MapGrid(-1.5, -3.0, 0.05, 60, 80)))
    f = _face_frame()
    pipe.face = FaceMap(f, (-1.0, 1.0), (-1.0, 1.0), FaceMapConfig(cell_m=0.1, seam_m=0.2))
    rng = np.random.default_rng(4)
    n = 4000
    on_face = f.to_world(np.column_stack([rng.uniform(-0.9, 0.9, n), rng.uniform(-0.7, 0.7, n), np.zeros(n)]))
    floor = np.column_stack([rng.uniform(-1, 1, n), rng.uniform(-2.5, -2.0, n), np.full(n, -3.0)])
    xyz = np.vstack([on_face, floor])
    parts = [(xyz, np.tile(np.eye(3)[None] * 1e-4, (2 * n, 1, 1)), None)]
    eye = f.to_world(np.array([[0.0, 0.0, 3.0]]))[0]  # in front of the face (it sees the face's outer side)
    placed = RegisteredPose(Registration("off", "test"), CameraPose(np.eye(3), eye), np.zeros((6, 6)), None)
    run_to_end(pipe.fuse_steps(placed, parts))
    assert pipe.face.map.mapped.sum() > 200 and np.abs(pipe.face.map.z[pipe.face.map.mapped]).max() < 0.02
    X, Y = pipe.map.grid.centers()
    assert pipe.map.mapped[Y < -1.9].sum() > 50  # the floor in front of the face: the gravity grid
    owned = pipe.face.face_owned(pipe.map.grid)
    assert not (pipe.map.mapped & owned).any()  # the face's inner band: not in the gravity grid


def test_sight_lines_carry_the_pose_error_and_reach_past_the_point() -> None:
    """A point whose sight line misses a robot by 10 cm at 3 m: kept when the point is exact,
    masked when its error (the camera pose's) is 5 cm every way at 6 m; a point in
    front of a robot it hides (a lip's flying pixel) is masked, one far in front is not."""
    box = BodyBox(np.array([0.0, 3.0, 0.0]), np.eye(3), np.array([0.2, 0.2, 0.2]), 0.0)
    team = TeamGeometry((box,), ())
    eye = np.zeros(3)
    cfg = MaskConfig(margin_m=0.02, pixel_rad=0.001)
    past = np.array([[0.0, 6.0, 0.6]])  # its sight line passes 0.1 m over the box's top at y = 3
    exact = np.tile(np.eye(3)[None] * 1e-8, (1, 1, 1))
    assert not team_mask(past, exact, team, cfg, eye=eye).any()
    lateral = np.eye(3)[None] * 0.05**2
    assert team_mask(past, lateral, team, cfg, eye=eye).all()
    front = np.array([[0.0, 2.0, 0.0], [0.0, 1.0, 0.0]])  # in front of the box, on its sight line
    assert team_mask(front, np.tile(exact, (2, 1, 1)), team, cfg, eye=eye).tolist() == [True, False]
    # the camera's own robot (its box within own_m): no reach past the point
    own = BodyBox(np.array([0.0, 0.5, -0.7]), np.eye(3), np.array([0.3, 0.3, 0.3]))
    ahead = np.array([[0.0, 0.45, -0.35]])  # on the sight line to the own box, short of it
    assert not team_mask(ahead, exact, TeamGeometry((own,), ()), cfg, eye=eye).any()


def test_inconsistent_views_keep_the_better_supported_surface() -> None:
    """Two views of a flat face 20 cm apart (beyond the gate): whichever comes first, the
    cell ends with the one of smaller variance (the other agent's wrong surface never wins)."""
    for order in ((0, 1), (1, 0)):
        face = FaceMap(_face_frame(), (0.0, 0.2), (0.0, 0.2), FaceMapConfig(cell_m=0.1, overhang_gap_m=0.5))
        rng = np.random.default_rng(5)
        u, v = rng.uniform(0.0, 0.2, 30), rng.uniform(0.0, 0.2, 30)  # each view sees the whole (flat) grid
        views = [(0.2, 4e-4), (0.0, 1e-5)]  # (w, point variance): the second is the better
        for k in order:
            w, var = views[k]
            cov = np.tile(np.eye(3)[None] * var, (30, 1, 1))
            face.merge_parts([(_points_on(face, u, v, np.full(30, w)), cov, None)])
        assert face.map.z[0, 0] == pytest.approx(0.0, abs=1e-6)
        assert face.map.var[0, 0] < 1e-4


def test_a_column_a_view_sees_mostly_beyond_the_slab_is_left_to_other_views() -> None:
    """Where the fitted plane stands off the true ground by more than the slab (the ground 0.6 m
    behind it), a view's points over the cell fall mostly behind the slab and go to the gravity
    grid; the few its noise carries into the slab are not the cell's surface and are not fused
    (``FaceMergeStats.beyond_slab``). A cell whose ground lies in the slab keeps every point,
    and without the view's whole points (``rays``) nothing is held back."""
    rng = np.random.default_rng(4)
    face = FaceMap(_face_frame(), (0.0, 0.2), (0.0, 0.1), FaceMapConfig(cell_m=0.1))
    k = 200
    u = np.concatenate([rng.uniform(0.0, 0.1, k), rng.uniform(0.1, 0.2, k)])
    v = rng.uniform(0.0, 0.1, 2 * k)
    w = np.concatenate([np.full(k, -0.6), np.full(k, 0.0)]) + rng.normal(0.0, 0.05, 2 * k)
    xyz = _points_on(face, u, v, w)
    cov = np.tile(np.eye(3)[None] * 0.05**2, (2 * k, 1, 1))
    view = [(xyz, cov, None)]
    to_face, _ = split_parts(view, face)
    assert 0 < len(to_face[0][0]) - k < k // 4  # the noise's tail of the far column reaches the slab
    st = face.merge_parts(to_face, eye=_points_on(face, np.array([0.1]), np.array([0.05]), np.array([3.0]))[0],
                          rays=view)
    assert not face.map.mapped[0, 0] and face.map.mapped[0, 1]
    assert st.beyond_slab == len(to_face[0][0]) - k
    alone = face.empty_like()
    assert alone.merge_parts(to_face).beyond_slab == 0 and alone.map.mapped[0, 0]


def test_a_column_the_views_see_mostly_beyond_the_slab_is_left_to_a_view_that_sees_a_sliver() -> None:
    """A view that sees a cell's whole column puts most of its points behind the slab (the ground
    0.6 m behind the plane); a later view that sees only a sliver of the column (a step's top
    inside the slab, the rest hidden) has all of its few points there. Counted per view, the
    second view's points would hold the cell 0.4 m off its ground; counted over the views so
    far (``FaceMap.column_in``, ``column_out``), the column lies mostly beyond the slab and the
    cell is left to the gravity grid, while its neighbour on the plane is mapped by both."""
    rng = np.random.default_rng(6)
    face = FaceMap(_face_frame(), (0.0, 0.2), (0.0, 0.1), FaceMapConfig(cell_m=0.1))
    eye = _points_on(face, np.array([0.1]), np.array([0.05]), np.array([3.0]))[0]
    k = 200
    u = np.concatenate([rng.uniform(0.0, 0.1, k), rng.uniform(0.1, 0.2, k)])
    v = rng.uniform(0.0, 0.1, 2 * k)
    w = np.concatenate([np.full(k, -0.6), np.full(k, 0.0)]) + rng.normal(0.0, 0.02, 2 * k)
    whole = [(_points_on(face, u, v, w), np.tile(np.eye(3)[None] * 0.02**2, (2 * k, 1, 1)), None)]
    m = 20  # the sliver: a step's top at w = -0.2 over the first cell, and the plane over the second
    u2 = np.concatenate([rng.uniform(0.0, 0.1, m), rng.uniform(0.1, 0.2, k)])
    v2 = rng.uniform(0.0, 0.1, m + k)
    w2 = np.concatenate([np.full(m, -0.2), np.full(k, 0.0)]) + rng.normal(0.0, 0.02, m + k)
    sliver = [(_points_on(face, u2, v2, w2), np.tile(np.eye(3)[None] * 0.02**2, (m + k, 1, 1)), None)]
    for view in (whole, sliver):
        to_face, _ = split_parts(view, face)
        face.merge_parts(to_face, eye=eye, rays=view)
    assert face.column_out[0] > face.column_in[0] >= m
    assert not face.map.mapped[0, 0] and face.map.mapped[0, 1]
    alone = face.empty_like()  # the sliver's view alone: its points are the cell's
    to_face, _ = split_parts(sliver, alone)
    alone.merge_parts(to_face, eye=eye, rays=sliver)
    assert alone.map.mapped[0, 0] and alone.map.z[0, 0] == pytest.approx(-0.2, abs=0.03)
