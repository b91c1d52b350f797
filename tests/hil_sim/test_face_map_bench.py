"""Both agents' views into the face map on the bench (``hil_sim.team.face_scene``,
``safer-hil experiment face-map``; docs/algorithm.md §8.1): a tiny seeded scene."""

from __future__ import annotations

import pytest

from hil_sim.cli import main
from hil_sim.team.face_scene import FaceScene


@pytest.mark.parametrize("argv", [
    ["experiment", "face-map", "--scenes", "0"],
    ["experiment", "face-map", "--jobs", "0"],
    ["experiment", "face-map", "--scenes", "1", "--scenario", "nowhere"],
    ["experiment", "face-map", "--results-name", "../elsewhere"],
    ["experiment", "face-map", "--results-name", "Face"],  # upper case: no results file name
    ["experiment", "face-map", "--resolve-cells", "nan"],
    ["experiment", "face-map", "--resolve-cells", "-1"],
])
def test_bad_input_exits_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(argv) == 2
    assert "Traceback" not in capsys.readouterr().err


@pytest.mark.slow
def test_the_team_is_masked_and_the_judge_sees_it_without() -> None:
    """A view from the Cliff-bot on the face with its own body, the tethers, the RECON-bot and
    the Anchorbots in the picture: masked, no point on them (judged on the truth) reaches the
    map and no cell of them is mapped; unmasked, the same view fuses such points."""
    from hil_sim.lab.experiments.experiment_face_map import COLUMNS

    row = FaceScene("cliff-team", 3, "config/fsw.toml").measure(0, 1)
    assert set(row) == set(COLUMNS)  # the experiment's CSV writes every figure a scene returns
    assert row["views"] == 1 and row["team_points_seen"] >= 10
    assert row["team_points_fused"] == 0 and row["team_cells_mapped"] == 0
    bare = FaceScene("cliff-team", 3, "config/fsw.toml", mask=False).measure(0, 1)
    assert bare["team_points_seen"] == row["team_points_seen"]  # the same view, seeded
    assert bare["team_points_fused"] > 0 and bare["team_cells_mapped"] > 0


def test_the_gravity_grid_is_queried_where_a_user_queries_it() -> None:
    """A plane at 75 deg, the gravity grid of 3 cm holding each cell's true centre height: at
    the true face points its query error is the staircase's, ``tan a * c / sqrt(12)`` RMS along
    the vertical; along the face normal the same grid is ``cos a`` of that off the surface."""
    import math

    import numpy as np

    from fsw.core.geometry import MapGrid
    from fsw.core.map.elevation_map import ElevationMap
    from fsw.core.map.face_map import FaceFrame, FaceMap, FaceMapConfig
    from hil_sim.team.face_eval import gravity_along_normal, gravity_at_points

    a = math.radians(75.0)
    frame = FaceFrame.from_normal(np.array([0.013, -0.5, -1.0]), np.array([0.0, -math.sin(a), math.cos(a)]))
    face = FaceMap(frame, (-0.5, 0.5), (-0.8, 0.8), FaceMapConfig(cell_m=0.059))
    grav = ElevationMap(MapGrid(-0.7, -1.2, 0.03, 47, 40))
    X, Y = grav.grid.centers()
    grav.z[:] = frame.plane_z(X, Y)
    grav.n[:] = 1
    cells = np.arange(face.grid.nx * face.grid.ny)
    e = gravity_at_points(grav, face, cells, np.zeros(len(cells)))
    e = e[np.isfinite(e)]
    assert len(e) > 0.9 * len(cells)
    rms = float(np.sqrt(np.mean(e * e)))
    assert rms == pytest.approx(math.tan(a) * 0.03 / math.sqrt(12), rel=0.2)
    en = gravity_along_normal(grav, face, cells)
    en = en[np.isfinite(en)]
    assert float(np.sqrt(np.mean(en * en))) == pytest.approx(rms * math.cos(a), rel=0.35)


def test_the_judge_counts_the_overhangs_a_sight_line_reached_under() -> None:
    """``overhang_seen``: a truth overhang cell counts as one a view could show when a true sight
    line crosses its column more than the gap under the outer surface; a sight line that stops
    before the column, or a single-surface cell, does not count."""
    import math

    import numpy as np

    from fsw.core.map.face_map import FaceFrame, FaceMap, FaceMapConfig
    from hil_sim.team.face_eval import overhang_seen

    a = math.radians(70.0)
    frame = FaceFrame.from_normal(np.zeros(3), np.array([0.0, -math.sin(a), math.cos(a)]))
    face = FaceMap(frame, (0.0, 0.3), (0.0, 0.1), FaceMapConfig(cell_m=0.1, overhang_gap_m=0.1))
    cells = np.array([0, 1, 2])
    w_true = np.array([0.4, 0.4, 0.0])
    over = np.array([True, True, False])
    eye = frame.to_world(np.array([[-1.0, 0.05, 0.1]]))[0]
    end = frame.to_world(np.array([[0.08, 0.05, 0.1], [0.28, 0.05, 0.1]]))
    assert overhang_seen(face, cells, w_true, over, [(eye, end[:1])]).tolist() == [True, False, False]
    assert overhang_seen(face, cells, w_true, over, [(eye, end)]).tolist() == [True, True, False]
    # along w = 0.35: under the roof, but by less than the gap
    high = frame.to_world(np.array([[-1.0, 0.05, 0.35], [0.28, 0.05, 0.35]]))
    assert not overhang_seen(face, cells, w_true, over, [(high[0], high[1:])]).any()



def _recon_sees_anchorbot(scene: FaceScene) -> dict[str, int]:
    """One RECON-bot view from the plateau, 2.5 m beside Anchorbot A, aimed at its foot, with the
    Cliff-bot on the face and both tethers in the picture; the masked and judged point counts."""
    import math

    import numpy as np

    from fsw.core.geometry import camera_pose_from_rover, point_mast
    from hil_sim.team.face_scene import RECON_SIGMA, pose_cov

    t = scene.world.team
    assert t is not None
    a = np.asarray(t.anchors_xy[0], float)
    rover = (float(a[0]) - 2.5, float(a[1]) - 0.3, 0.0)
    joints, _ = point_mast(rover, np.array([a[0], a[1], 0.0]), scene.cfg.mast, 0.3)
    pose = camera_pose_from_rover(rover, joints, scene.cfg.mast)
    _, _, team, body = scene.cliffbot_at(0.45, 0.0, rover)
    scene._view("recon", pose, pose_cov(RECON_SIGMA), team, body, scene.known(team, np.zeros(3)))
    assert math.isfinite(float(pose.t[2]))
    return {"seen": scene.team_points, "fused": scene.team_points_fused, "cells": len(scene.team_cells)}


class _NoAnchorbots(FaceScene):
    """The RECON-bot's mask without the Anchorbots' boxes (its mask before they were known)."""

    def known(self, team, cliff_err):  # type: ignore[no-untyped-def]
        import dataclasses

        geo = super().known(team, cliff_err)
        return dataclasses.replace(geo, boxes=geo.boxes[:2])


@pytest.mark.slow
def test_the_recon_bots_views_keep_the_anchorbots_out() -> None:
    """A RECON-bot view of an Anchorbot, the tethers and the Cliff-bot, masked as the flight knows
    them (the Anchorbots on their surveyed ground points, the ground under the tethers kept): no
    point on them (judged on the truth) reaches the map; without the Anchorbots' boxes their
    points are mapped as terrain."""
    row = _recon_sees_anchorbot(FaceScene("cliff-team", 1, "config/fsw.toml"))
    assert row["seen"] >= 100
    assert row["fused"] == 0 and row["cells"] == 0
    bare = _recon_sees_anchorbot(_NoAnchorbots("cliff-team", 1, "config/fsw.toml"))
    assert bare["seen"] == row["seen"]  # the same view, seeded
    assert bare["fused"] > 0 and bare["cells"] > 0


def test_the_judge_tells_a_sliver_of_air_from_an_overhang() -> None:
    """``air_gap_along_normal``: on a 70 deg face, a ledge block standing out along the normal
    from 0.15 m to 0.35 m over a cell leaves 0.15 m of air under it (two surfaces a view can tell
    apart); the same block from 0.01 m leaves a sliver. The truth counts both as overhangs (the
    first and last crossings are more than the gap apart)."""
    import math

    import numpy as np

    from fsw.core.map.face_map import FaceFrame, FaceMap, FaceMapConfig
    from hil_sim.team.face_eval import air_gap_along_normal, truth_along_normal

    a = math.radians(70.0)
    frame = FaceFrame.from_normal(np.zeros(3), np.array([0.0, -math.sin(a), math.cos(a)]))
    face = FaceMap(frame, (-0.05, 0.15), (-0.05, 0.15), FaceMapConfig(cell_m=0.1, overhang_gap_m=0.1))

    class Ledge:
        def __init__(self, w0: float, w1: float) -> None:
            self.y = (-w1 * math.sin(a), -w0 * math.sin(a))  # the block's span along y under the normal

        def ground_at(self, x: object, y: object) -> object:
            yy = np.asarray(y, float)
            block = (yy >= self.y[0]) & (yy <= self.y[1])
            return math.tan(a) * yy + np.where(block, 0.5, 0.0) + 0.0 * np.asarray(x, float)

    cells = np.array([0])
    for w0, gap in ((0.15, 0.15), (0.01, 0.01)):
        world = Ledge(w0, 0.35)
        _, over = truth_along_normal(world, face, cells)  # type: ignore[arg-type]
        assert over.tolist() == [True]
        got = air_gap_along_normal(world, face, cells)  # type: ignore[arg-type]
        assert got[0] == pytest.approx(gap, abs=0.011)


def test_the_judge_counts_the_overhangs_the_views_show_as_two_surfaces() -> None:
    """``overhang_shown``: the ledge block standing out from 0.15 m to 0.35 m along the normal is
    shown as two surfaces by a view that sees its inner side (the step facing up the face, where
    the normal passes from air into the block), not by one that sees only its outer side from
    straight out along the normal (no sight line under it)."""
    import math

    import numpy as np

    from fsw.core.map.face_map import FaceFrame, FaceMap, FaceMapConfig
    from hil_sim.team.face_eval import overhang_shown, truth_along_normal

    a = math.radians(70.0)
    frame = FaceFrame.from_normal(np.zeros(3), np.array([0.0, -math.sin(a), math.cos(a)]))
    face = FaceMap(frame, (-0.05, 0.15), (-0.05, 0.15), FaceMapConfig(cell_m=0.1, overhang_gap_m=0.1))
    y_block = (-0.35 * math.sin(a), -0.15 * math.sin(a))

    class Ledge:
        def ground_at(self, x: object, y: object) -> object:
            yy = np.asarray(y, float)
            block = (yy >= y_block[0]) & (yy <= y_block[1])
            return math.tan(a) * yy + np.where(block, 0.5, 0.0) + 0.0 * np.asarray(x, float)

    world = Ledge()
    cells = np.array([0])
    w_true, over = truth_along_normal(world, face, cells)  # type: ignore[arg-type]
    assert over.tolist() == [True]
    step = frame.to_world(np.array([[0.0, 0.0, 0.15]]))  # on the block's inner side
    above = step[0] + np.array([0.0, 1.0, 0.3])  # up the face, out over the crevice
    outer = frame.to_world(np.array([[0.0, 0.0, 0.35], [0.0, 0.0, 2.0]]))
    shown = overhang_shown(world, face, cells, w_true, over, [(above, step)])  # type: ignore[arg-type]
    assert shown.tolist() == [True]
    shown = overhang_shown(world, face, cells, w_true, over, [(outer[1], outer[:1])])  # type: ignore[arg-type]
    assert shown.tolist() == [False]


def test_the_judge_finds_an_overhang_off_a_cells_centre() -> None:
    """``overhang_in_cell``: a ledge block that covers only one side of a cell (x > 1 cm) is no
    truth overhang at the cell's centre but lies under two of its quarter-centres; a cell of
    plain face holds none."""
    import math

    import numpy as np

    from fsw.core.map.face_map import FaceFrame, FaceMap, FaceMapConfig
    from hil_sim.team.face_eval import overhang_in_cell, truth_along_normal

    a = math.radians(70.0)
    frame = FaceFrame.from_normal(np.zeros(3), np.array([0.0, -math.sin(a), math.cos(a)]))
    face = FaceMap(frame, (-0.05, 0.15), (-0.05, 0.15), FaceMapConfig(cell_m=0.1, overhang_gap_m=0.1))
    y_block = (-0.35 * math.sin(a), -0.15 * math.sin(a))

    class HalfLedge:
        def __init__(self, height: float) -> None:
            self.height = height

        def ground_at(self, x: object, y: object) -> object:
            xx, yy = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
            block = (yy >= y_block[0]) & (yy <= y_block[1]) & (xx > 0.01)
            return math.tan(a) * yy + np.where(block, self.height, 0.0)

    cells = np.array([0])
    _, over = truth_along_normal(HalfLedge(0.5), face, cells)  # type: ignore[arg-type]
    assert over.tolist() == [False]
    assert overhang_in_cell(HalfLedge(0.5), face, cells).tolist() == [True]  # type: ignore[arg-type]
    assert overhang_in_cell(HalfLedge(0.0), face, cells).tolist() == [False]  # type: ignore[arg-type]


def test_relief_rise_finds_the_cells_beside_a_step_of_the_truth() -> None:
    """A 45 deg face with a ledge raised 0.2 m (0.14 m along the normal) across a strip: the
    cells within 2 cells of its top see the rise, those on its top and 3 cells or more from it
    see none; the cell whose normal crosses the ledge's vertical wall twice is no single surface."""
    import numpy as np

    from fsw.core.map.face_map import FaceFrame, FaceMap, FaceMapConfig
    from hil_sim.team.face_eval import relief_rise

    frame = FaceFrame.from_normal(np.zeros(3), np.array([0.0, -1.0, 1.0]))
    face = FaceMap(frame, (0.0, 1.2), (0.0, 1.2), FaceMapConfig(cell_m=0.1))

    class Ledge:
        def ground_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
            v = frame.to_face(np.column_stack([np.ravel(x), np.ravel(y), np.ravel(frame.plane_z(x, y))]))[:, 1]
            on = ((v >= 0.6) & (v < 0.8)).reshape(np.shape(x))
            return np.asarray(frame.plane_z(x, y) + np.where(on, 0.2, 0.0))

    rise = relief_rise(Ledge(), face).reshape(face.grid.shape)  # type: ignore[arg-type]
    col = rise[:, 5]  # one column along the dip; row 7 on the ledge's top, row 6 partly
    assert np.all(col[[5, 9]] >= 0.1)  # within 2 cells of the top, below and above it
    assert np.all(np.abs(col[[0, 1, 2, 3, 7, 10, 11]]) < 0.02)  # on the top, and 3 or more cells off
    assert np.isnan(col[8])


def test_the_miss_diagnostic_finds_the_inner_surface_under_a_ledge() -> None:
    """``overhang_why.first_crossing``: under the ledge block standing out from 0.15 m to 0.35 m
    along the normal of a 70 deg face, the normal first leaves the ground at the face (w = 0, the
    inner surface) and last at the block's outer side; with no block, both are the face."""
    import math

    import numpy as np

    from fsw.core.map.face_map import FaceFrame, FaceMap, FaceMapConfig
    from hil_sim.team.face_eval import truth_along_normal
    from hil_sim.team.overhang_why import first_crossing

    a = math.radians(70.0)
    frame = FaceFrame.from_normal(np.zeros(3), np.array([0.0, -math.sin(a), math.cos(a)]))
    face = FaceMap(frame, (-0.05, 0.15), (-0.05, 0.15), FaceMapConfig(cell_m=0.1, overhang_gap_m=0.1))

    class Ledge:
        def __init__(self, height: float) -> None:
            self.height = height

        def ground_at(self, x: object, y: object) -> object:
            yy = np.asarray(y, float)
            block = (yy >= -0.35 * math.sin(a)) & (yy <= -0.15 * math.sin(a))
            return math.tan(a) * yy + np.where(block, self.height, 0.0) + 0.0 * np.asarray(x, float)

    cells = np.array([0])
    for height, over_true in ((0.5, True), (0.0, False)):
        world = Ledge(height)
        w_out, over = truth_along_normal(world, face, cells)  # type: ignore[arg-type]
        w_in = first_crossing(world, face, cells)  # type: ignore[arg-type]
        assert over.tolist() == [over_true]
        assert w_in[0] == pytest.approx(0.0, abs=0.006)
        assert (w_out[0] - w_in[0] > 0.1) == over_true


def test_the_judge_finds_the_ground_facing_the_face_a_view_sees() -> None:
    """``facing_seen``: a view whose true sight line ends on the ledge block's inner side (the step
    facing up the face, where the normal passes from air into the block) shows the cell's facing
    ground; one that sees only the block's outer side does not, nor does a view of plain face."""
    import math

    import numpy as np

    from fsw.core.map.face_map import FaceFrame, FaceMap, FaceMapConfig
    from hil_sim.team.face_eval import facing_seen

    a = math.radians(70.0)
    frame = FaceFrame.from_normal(np.zeros(3), np.array([0.0, -math.sin(a), math.cos(a)]))
    face = FaceMap(frame, (-0.05, 0.15), (-0.05, 0.15), FaceMapConfig(cell_m=0.1, overhang_gap_m=0.1))
    y_block = (-0.35 * math.sin(a), -0.15 * math.sin(a))

    class Ledge:
        def __init__(self, height: float) -> None:
            self.height = height

        def ground_at(self, x: object, y: object) -> object:
            yy = np.asarray(y, float)
            block = (yy >= y_block[0]) & (yy <= y_block[1])
            return math.tan(a) * yy + np.where(block, self.height, 0.0) + 0.0 * np.asarray(x, float)

    step = frame.to_world(np.array([[0.0, 0.0, 0.15]]))  # on the block's inner side
    above = step[0] + np.array([0.0, 1.0, 0.3])  # up the face, out over the crevice
    outer = frame.to_world(np.array([[0.0, 0.0, 0.35], [0.0, 0.0, 2.0]]))
    block = Ledge(0.5)
    # per cell of the face map's grid (flat); the points lie in cell 0
    assert facing_seen(block, face, [(above, step)]).tolist() == [True, False, False, False]  # type: ignore[arg-type]
    assert not facing_seen(block, face, [(outer[1], outer[:1])]).any()  # type: ignore[arg-type]
    plain = frame.to_world(np.array([[0.0, 0.0, 0.0]]))
    assert not facing_seen(Ledge(0.0), face, [(above, plain)]).any()  # type: ignore[arg-type]


def test_the_misses_name_a_face_plane_fitted_off_the_face() -> None:
    """``frame_off_deg``: 0 for a face map laid in the scenario's face (falling toward -y at its
    slope), the angle between the normals for a plane turned about the vertical, None without a
    team."""
    import math
    from types import SimpleNamespace

    import numpy as np

    from fsw.core.map.face_map import FaceFrame, FaceMap, FaceMapConfig
    from hil_sim.team.face_eval import frame_off_deg

    a, turn = math.radians(70.0), math.radians(30.0)
    world = SimpleNamespace(team=SimpleNamespace(face_slope_deg=70.0))
    on = FaceFrame.from_normal(np.zeros(3), np.array([0.0, -math.sin(a), math.cos(a)]))
    off = FaceFrame.from_normal(np.zeros(3), np.array([math.sin(a) * math.sin(turn),
                                                       -math.sin(a) * math.cos(turn), math.cos(a)]))
    cfg = FaceMapConfig(cell_m=0.1)
    assert frame_off_deg(world, FaceMap(on, (0.0, 1.0), (0.0, 1.0), cfg)) == pytest.approx(0.0, abs=1e-6)  # type: ignore[arg-type]
    expected = math.degrees(math.acos(math.sin(a) ** 2 * math.cos(turn) + math.cos(a) ** 2))
    assert frame_off_deg(world, FaceMap(off, (0.0, 1.0), (0.0, 1.0), cfg)) == pytest.approx(expected, abs=1e-6)  # type: ignore[arg-type]
    assert frame_off_deg(SimpleNamespace(team=None), FaceMap(on, (0.0, 1.0), (0.0, 1.0), cfg)) is None  # type: ignore[arg-type]


def test_the_true_face_plane_is_the_whole_faces() -> None:
    """``true_face_normal``: on a plain face (no ledges, relief or jumble) the plane of the truth
    is the scenario's slope; ledges make the face, lip to foot, fall less steeply than that."""
    import math

    from hil_sim.team.face_eval import true_face_normal
    from hil_sim.world import load_scenario

    plain = true_face_normal(load_scenario("cliff-team?ledges=0&face_slope_deg=70&face_roughness_m=0&jumble_k=0", 4))
    ledged = true_face_normal(load_scenario("cliff-team?ledges=3&face_slope_deg=70", 4))
    assert plain is not None and ledged is not None
    assert math.degrees(math.acos(plain[2])) == pytest.approx(70.0, abs=1.0)
    assert plain[1] < -0.9  # falling toward -y
    assert math.degrees(math.acos(ledged[2])) < 67.0




def test_the_facing_test_takes_facing_ground_seen_close_and_refuses_it_seen_far() -> None:
    """The facing test on a patch 5 cm across facing the face (its normal 45 deg into it, up the
    dip), seen from up the dip: with 2 mm of depth noise (a view at arm's length) it counts the
    patch's points, with 4 cm (the RECON-bot's from the plateau, metres away) none: the plane's
    normal is then uncertain by tens of degrees (the missed cells' ``facing_far``). A patch facing
    out of the face is counted at neither."""
    import numpy as np

    from fsw.core.geometry import MapGrid
    from fsw.core.map.face_map import FaceMapConfig
    from fsw.core.map.overhang import Overhangs

    cfg = FaceMapConfig(cell_m=0.06)
    g = MapGrid(-0.12, -0.12, 0.06, 4, 4)
    iy, ix, _ = g.cell_index(np.array([0.0]), np.array([0.0]))
    cell = int(iy[0]) * g.nx + int(ix[0])
    rng = np.random.default_rng(3)
    eye = np.array([0.0, 1.5, 0.1])  # face frame: up the dip, just out of the face
    ab = rng.uniform(-0.025, 0.025, (400, 2))
    for n_w, facing in ((-0.71, True), (0.71, False)):
        n = np.array([0.0, 0.71, n_w])
        n /= np.linalg.norm(n)
        e1 = np.array([1.0, 0.0, 0.0])
        e2 = np.cross(n, e1)
        clean = np.array([0.0, 0.0, 0.3]) + ab[:, :1] * e1 + ab[:, 1:] * e2
        d = eye - clean
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        counts = {}
        for sd in (0.04, 0.002):
            noise = sd**2 * d[:, :, None] * d[:, None, :] + 0.001**2 * np.eye(3)[None]
            q = clean + d * rng.normal(0.0, sd, (len(clean), 1)) + rng.normal(0.0, 0.001, clean.shape)
            jy, jx, _ = g.cell_index(q[:, 0], q[:, 1])
            hits, _ = Overhangs(g.shape).facing_the_face(g, cfg, eye, q, noise)
            counts[sd] = int((hits & (jy * g.nx + jx == cell)).sum())
        assert counts[0.04] == 0
        assert (counts[0.002] >= cfg.facing_min_points) if facing else (counts[0.002] == 0)


def test_the_misses_say_which_agent_showed_the_facing_ground() -> None:
    """``facing_seen_by``: the ledge's facing step seen by the RECON-bot's view only is the
    RECON-bot's, not the Cliff-bot's (whose view sees plain face)."""
    import math

    import numpy as np

    from fsw.core.map.face_map import FaceFrame, FaceMap, FaceMapConfig
    from hil_sim.team.overhang_why import facing_seen_by

    a = math.radians(70.0)
    frame = FaceFrame.from_normal(np.zeros(3), np.array([0.0, -math.sin(a), math.cos(a)]))
    face = FaceMap(frame, (-0.05, 0.15), (-0.05, 0.15), FaceMapConfig(cell_m=0.1, overhang_gap_m=0.1))

    class Ledge:
        def ground_at(self, x: object, y: object) -> object:
            yy = np.asarray(y, float)
            block = (yy >= -0.35 * math.sin(a)) & (yy <= -0.15 * math.sin(a))
            return math.tan(a) * yy + np.where(block, 0.5, 0.0) + 0.0 * np.asarray(x, float)

    step = frame.to_world(np.array([[0.0, 0.0, 0.15]]))  # on the block's inner side
    outer = frame.to_world(np.array([[0.0, 0.0, 0.35], [0.0, 0.0, 2.0]]))
    rays = [(step[0] + np.array([0.0, 1.0, 0.3]), step), (outer[1], outer[:1])]
    seen = facing_seen_by(Ledge(), face, rays, ["recon", "cliffbot"])  # type: ignore[arg-type]
    assert seen["recon"].tolist() == [True, False, False, False] and not seen["cliffbot"].any()
    seen = facing_seen_by(Ledge(), face, rays[::-1], ["recon", "cliffbot"])  # type: ignore[arg-type]
    assert seen["cliffbot"].tolist() == [True, False, False, False] and not seen["recon"].any()


def test_the_false_flags_are_sorted_by_test_agent_and_what_the_truth_holds() -> None:
    """``overhang_why.false_flags`` on a plain 70 deg face (one surface everywhere): a cell flagged
    by the facing test from a RECON-bot view whose height lies 0.3 m out of the face holds a wrong
    surface; one flagged from below by a Cliff-bot view, its height on the face, is none of the
    truth's classes; a truly flagged cell would not count (there is none on a plain face)."""
    import math
    from types import SimpleNamespace

    import numpy as np

    from fsw.core.map.face_map import FaceFrame, FaceMap, FaceMapConfig
    from fsw.core.map.overhang import FLAG_TESTS
    from hil_sim.team.overhang_why import false_flags

    a = math.radians(70.0)
    frame = FaceFrame.from_normal(np.zeros(3), np.array([0.0, -math.sin(a), math.cos(a)]))
    face = FaceMap(frame, (0.0, 0.5), (0.0, 0.5), FaceMapConfig(cell_m=0.1, overhang_gap_m=0.1))
    world = SimpleNamespace(ground_at=lambda x, y: math.tan(a) * np.asarray(y, float) + 0.0 * np.asarray(x, float))
    face.map.z[:] = 0.0
    face.map.var[:] = 1e-4
    face.map.n[:] = 1
    face.map.z[1, 1] = 0.3
    agent = np.full(face.grid.shape, "", object)
    for (iy, ix), test, who in (((1, 1), "facing", "recon"), ((3, 2), "underside", "cliffbot")):
        cell = np.zeros(face.grid.shape, bool)
        cell[iy, ix] = True
        face.overhangs.flag(cell, test)
        agent[iy, ix] = who
    assert face.flagged_by[1, 1] == FLAG_TESTS.index("facing") and face.overhang.sum() == 2
    out = false_flags(SimpleNamespace(face=face, flag_agent=agent, world=world))  # type: ignore[arg-type]
    assert out["ff_facing"] == 1 and out["ff_facing_recon"] == 1 and out["ff_facing_wrong_surface"] == 1
    assert out["ff_underside"] == 1 and out["ff_underside_cliffbot"] == 1 and out["ff_underside_other"] == 1
    assert sum(out[f"ff_{t}"] for t in FLAG_TESTS[1:]) == 2  # the two flags, each under its test
