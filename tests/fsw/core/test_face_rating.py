"""Rating views of a face on the face's own grid (fsw.core.planning.face_rating, docs/algorithm.md
§8.2): a camera on a 70 deg face expects the face below it that the gravity grid's prior cannot
predict; a camera behind the plane expects none of it; the chosen view's face cells stand for
their gravity cells in the team's ``planned``."""

from __future__ import annotations

import math

import numpy as np

from fsw.core.geometry import CameraConfig, CameraPose, MapGrid
from fsw.core.map.elevation_map import ElevationMap
from fsw.core.map.face_map import FaceFrame, FaceMap, FaceMapConfig
from fsw.core.planning.face_rating import (
    face_cells,
    face_visibility,
    gravity_with_floor,
    rate_face_station,
    terrain_visibility,
)
from fsw.core.planning.nbv import NbvConfig, rate_station
from fsw.core.planning.team_views import AgentViews, ViewCentre, choose_team_views
from fsw.core.planning.visibility import terrain_from_map
from fsw.settings import load_settings

GRID = MapGrid(0.0, 0.0, 0.1, 60, 60)  # plateau y > 4 m at z = 0, a 70 deg face below it
SLOPE = math.radians(70.0)
CAM = CameraConfig(width_px=160, height_px=120, hfov_deg=60.0, baseline_m=0.07, min_range_m=0.3, max_range_m=4.0)
VIS = NbvConfig().visibility
YAWS = np.radians(np.arange(-180.0, 180.0, 30.0))
TILTS = np.radians([-75.0, -50.0, -25.0, 0.0])


def _plateau_only() -> ElevationMap:
    """The gravity map after a survey from the top: the plateau known, the face unknown."""
    emap = ElevationMap(GRID, load_settings(check_calibration=False).fusion)
    _, y = GRID.centers()
    top = y > 4.0
    emap.z[top] = 0.0
    emap.var[top] = 0.01**2
    emap.n[top] = 1
    return emap


def _face() -> FaceMap:
    """An empty face map in the face's plane (through the edge line y = 4, z = 0)."""
    normal = np.array([0.0, -math.sin(SLOPE), math.cos(SLOPE)])
    frame = FaceFrame.from_normal(np.array([3.0, 4.0, 0.0]), normal)
    return FaceMap(frame, (-3.0, 3.0), (-3.0, -0.2), FaceMapConfig(cell_m=0.1))


def _on_face(depth_m: float, out_m: float = 0.5) -> tuple[float, float, float]:
    """A camera ``out_m`` off the face, ``depth_m`` below the edge."""
    n = np.array([0.0, -math.sin(SLOPE), math.cos(SLOPE)])
    p = np.array([3.0, 4.0 - depth_m / math.tan(SLOPE), -depth_m]) + out_m * n
    return float(p[0]), float(p[1]), float(p[2])


def test_a_camera_on_the_face_expects_the_face_the_gravity_prior_cannot_see() -> None:
    emap = _plateau_only()
    fc = face_cells(_face(), emap, VIS, prior_m=1.0)
    cam = _on_face(1.0)
    face = rate_face_station(fc, cam, YAWS, TILTS, 2, np.asarray(emap.interest, float), CAM, VIS)
    down = int(np.argmin(np.abs(YAWS + math.pi / 2)))  # facing out of the face (-y)
    assert face.expected_new_cells[down, 0] > 40  # 75 deg down: along the face below, at arm's length
    assert face.expected_new_cells[down, 3] == 0.0  # level, out into the air: none of the face
    behind = rate_face_station(fc, (3.0, 4.5, 0.45), YAWS, TILTS, 2, None, CAM, VIS)  # on the plateau
    assert behind.cells_rated == 0 and behind.expected_new_cells.max() == 0.0
    # the gravity grid alone: its prior puts the unknown face at the plateau's height
    grav = rate_station(terrain_from_map(emap.z, emap.var, GRID, VIS), cam, YAWS, TILTS, emap.n, 2,
                        np.asarray(emap.interest, float), CAM, VIS)
    assert grav.expected_new_cells[down, 0] < 0.5 * face.expected_new_cells[down, 0]


def test_the_face_cells_stand_for_their_gravity_cells_and_the_floor_prior_lies_below() -> None:
    emap = _plateau_only()
    fc = face_cells(_face(), emap, VIS, prior_m=1.0)
    _, y = GRID.centers()
    assert not fc.owned[y > 4.05].any()  # the plateau is the gravity grid's
    assert fc.owned.sum() > 100 and fc.below.any() and not (fc.owned & fc.below).any()
    assert fc.floor_z < -3.0  # the plane at the face cells' lowest v (band 3 m + prior 1 m of dip)
    terrain = gravity_with_floor(fc, emap, VIS)
    assert np.allclose(terrain.elev_m[fc.below], fc.floor_z)
    pose = CameraPose.from_pan_tilt(*_on_face(1.0), -math.pi / 2, math.radians(-75.0))
    pv = face_visibility(fc, pose, CAM, VIS, GRID)
    assert pv.max() > 0.5 and not (pv > 0)[~fc.owned].any()


def test_the_cliffbots_face_view_enters_planned_on_its_gravity_cells() -> None:
    """Rated on the face cells, the Cliff-bot's view is no blind one, and the cells it will see go
    into the team's ``planned`` as the gravity cells the next agent's rating reads."""
    emap = _plateau_only()
    fc = face_cells(_face(), emap, VIS, prior_m=1.0)
    k = YAWS.size * TILTS.size
    cliff = AgentViews("cliffbot", CAM, (ViewCentre(_on_face(1.0), YAWS, TILTS, np.zeros(k), np.zeros(k),
                                                     (3.0, 3.6, 1.0, 1.0)),), face=fc)
    views, planned = choose_team_views(emap, [cliff], NbvConfig())
    assert views[0].expected_new_cells > 40 and "no view is expected" not in views[0].why
    assert planned[fc.owned].max() > 0.5 and planned[~fc.owned & ~fc.below].max() == 0.0


def test_the_ground_beyond_the_lip_falls_at_the_faces_dip_not_at_the_lips_height() -> None:
    """Unknown ground past the lip that no face cell stands for (the face map's band starts 1 m
    down the dip) is rated at most at the face's dip continued from the lip, never below the
    floor prior; an unknown patch up the dip keeps its known neighbours' height. From the
    plateau, the view over the lip then expects fewer new cells than on the lip-height prior."""
    emap = _plateau_only()
    x, y = GRID.centers()
    hole = (y > 5.0) & (y < 5.4) & (x > 2.0) & (x < 2.4)
    emap.z[hole], emap.var[hole], emap.n[hole] = np.nan, np.inf, 0
    normal = np.array([0.0, -math.sin(SLOPE), math.cos(SLOPE)])
    face = FaceMap(FaceFrame.from_normal(np.array([3.0, 4.0, 0.0]), normal), (-3.0, 3.0), (-3.0, -1.0),
                   FaceMapConfig(cell_m=0.1))
    fc = face_cells(face, emap, VIS, prior_m=1.0)
    terrain = gravity_with_floor(fc, emap, VIS)
    plain = terrain_from_map(emap.z, emap.var, GRID, VIS)
    past = (y < 4.0) & ~fc.owned & ~fc.below
    assert past.sum() > 100
    dip = np.maximum(fc.floor_z, -math.tan(SLOPE) * (4.05 - y[past]))  # from the last known row, y = 4.05
    assert np.allclose(terrain.elev_m[past], np.minimum(plain.elev_m[past], dip), atol=1e-9)
    assert (terrain.elev_m[past] < plain.elev_m[past] - 0.25).all()  # a cell past the lip: 0.27 m lower
    assert terrain.elev_m[~np.isnan(emap.z)].tolist() == emap.z[~np.isnan(emap.z)].tolist()
    assert np.allclose(terrain.elev_m[hole], plain.elev_m[hole]) and (terrain.elev_m >= fc.floor_z - 1e-9).all()
    cam = (3.0, 5.0, 1.5)  # 1 m behind the lip, 1.5 m up, looking over it (yaw -90 deg) at those cells
    new = [rate_station(t, cam, YAWS, np.radians([-30.0]), emap.n, 2, past.astype(float), CAM, VIS)
           .expected_new_cells[3, 0] for t in (terrain, plain)]
    assert new[1] > 20 and new[0] < 0.7 * new[1]


def test_a_known_face_cell_stands_for_the_gravity_cell_under_its_own_point() -> None:
    """A face cell the face map knows 0.3 m off the plane (a ledge): on the 70 deg face its point
    lies columns away from the plane's foot, and it stands for the gravity cell under its point.
    Standing for the plane's foot, it took that unmapped column out of the gravity rating while
    adding nothing (it is measured), and a view of the ledge recorded a miss there (§3.4)."""
    emap = _plateau_only()
    face = _face()
    fm = face.map
    ky, kx = fm.grid.ny // 2, fm.grid.nx // 2
    fm.z[ky, kx], fm.var[ky, kx], fm.n[ky, kx] = 0.3, 0.01**2, 2
    fc = face_cells(face, emap, VIS, prior_m=1.0)
    pad = fc.grid.ny - fm.grid.ny
    point = fc.world[pad + ky, kx]
    under = GRID.cell_index(point[:1], point[1:2])
    assert (fc.gy[pad + ky, kx], fc.gx[pad + ky, kx]) == (int(under[0][0]), int(under[1][0]))
    u, v = fm.grid.centers()
    foot = face.frame.origin + face.frame.R @ np.array([u[ky, kx], v[ky, kx], 0.0])
    fy, fx, _ = GRID.cell_index(foot[:1], foot[1:2])
    assert abs(int(fy[0]) - int(under[0][0])) >= 2  # the ledge is not over the plane's foot
    # a view of the ledge expects its own column there, not the plane's foot
    cam = point + 1.0 * face.frame.R[:, 2] + 0.6 * face.frame.R[:, 1]  # out of the face, up its dip
    yaw = math.atan2(point[1] - cam[1], point[0] - cam[0])
    tilt = math.atan2(point[2] - cam[2], math.hypot(point[0] - cam[0], point[1] - cam[1]))
    pv = face_visibility(fc, CameraPose.from_pan_tilt(*cam, yaw, tilt), CAM, VIS, GRID)
    assert pv[int(under[0][0]), int(under[1][0])] > 0.5


def _on_face_looking_out(depth_m: float, tilt_deg: float) -> CameraPose:
    """A camera 0.5 m off the face, ``depth_m`` below the edge, looking out of it (-y) and down."""
    return CameraPose.from_pan_tilt(*_on_face(depth_m), -math.pi / 2, math.radians(tilt_deg))


def test_the_floor_prior_is_a_prior_not_ground() -> None:
    """The unknown ground in front of the face takes the unknown cells' exponent of §3.1, not a
    known cell's: from the face, a floor cell past a metre of floor prior is expected visible
    (with the known cells' exponent a dozen factors near one half hide it)."""
    emap = _plateau_only()
    fc = face_cells(_face(), emap, VIS, prior_m=1.0)
    terrain = gravity_with_floor(fc, emap, VIS)
    assert np.allclose(terrain.weight[fc.below], GRID.cell / VIS.prior_corr_len_m)
    assert np.all(terrain.weight[~np.isnan(emap.z)] == 1.0)
    pose = _on_face_looking_out(3.0, -35.0)
    x, y = GRID.centers()
    target = fc.below & (np.abs(x - 3.0) < 0.05) & (np.abs(y - 1.05) < 0.05)  # 1.4 m out, on the floor prior
    assert target.sum() == 1
    pv = terrain_visibility(terrain, pose, CAM, VIS)
    assert pv[target][0] > 0.5


def test_the_ground_in_front_of_the_face_continues_the_known_ground_there() -> None:
    """Where ground in front of the face is known (a talus 0.76 m above the floor prior), the
    unknown ground beside it is rated at its height as §3.1 continues known ground, not at the
    foot of the face cells; with none known it is the foot."""
    emap = _plateau_only()
    x, y = GRID.centers()
    talus = (y > 1.6) & (y < 2.2)
    emap.z[talus], emap.var[talus], emap.n[talus] = -3.0, 0.02**2, 1
    fc = face_cells(_face(), emap, VIS, prior_m=1.0)
    terrain = gravity_with_floor(fc, emap, VIS)
    front = fc.below & (y < 1.6)
    assert front.sum() > 100 and fc.floor_z < -3.5
    assert np.allclose(terrain.elev_m[front], -3.0, atol=0.01)
    assert np.allclose(gravity_with_floor(fc, _plateau_only(), VIS).elev_m[fc.below], fc.floor_z)
