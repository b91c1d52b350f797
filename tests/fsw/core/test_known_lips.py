"""The lips the map already knows (fsw.core.map.known_lips): a view that finds no lip of its own
along a drop the map knows, merged with a horizontal pose error, places none of its plateau
heights past it (issue 27)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fsw.core.geometry import CameraPose, MapGridConfig
from fsw.core.map.known_lips import KnownLips
from fsw.core.pipeline import RegisteredPose, SensingPipeline
from fsw.core.registration.registration import Registration
from fsw.core.steps import run_to_end
from fsw.core.stereo.stereo import StereoPoints
from fsw.settings import FswConfig, load_settings

CELL = 0.03
CAMERA = CameraPose(np.eye(3), np.array([0.0, 1.0, 2.0]))  # axes along the world's: camera = world - t


@pytest.fixture(scope="module")
def cfg() -> FswConfig:
    grid = MapGridConfig(origin_x_m=-1.5, origin_y_m=-1.5, cell_m=CELL, nx=100, ny=100)
    return dataclasses.replace(load_settings(), map=grid)


def _plateau(n: int, y0: float, y1: float, z: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-1.0, 1.0, n), rng.uniform(y0, y1, n), z + rng.normal(0, 0.003, n)])


def _view(xyz_w: np.ndarray, sigma_xy: float, near_w: np.ndarray | None = None,
          far_w: np.ndarray | None = None) -> tuple[RegisteredPose, StereoPoints]:
    """A view of world points (with its lips) whose pose is known to ``sigma_xy`` horizontally."""
    n = xyz_w.shape[0]
    cov_c = np.tile(np.diag([1e-6, 1e-6, 1e-6]), (n, 1, 1))
    lips = {} if near_w is None or far_w is None else {
        "lip_near_c": CAMERA.world_to_camera(near_w), "lip_far_c": CAMERA.world_to_camera(far_w)}
    pts = StereoPoints(CAMERA.world_to_camera(xyz_w), cov_c, np.zeros((n, 2)), np.ones(n), np.ones((1, n), bool),
                       **lips)
    cov = np.zeros((6, 6))
    cov[3, 3] = cov[4, 4] = sigma_xy**2
    return RegisteredPose(Registration("off", "test"), CAMERA, cov, None), pts


def _seed(pipe: SensingPipeline, xyz: np.ndarray) -> None:
    """Merge points into the pipeline's map (1 cm sigma)."""
    pipe.map.merge(xyz, var_z=np.full(xyz.shape[0], 1e-4))


def _merged_points(pipe: SensingPipeline, placed: RegisteredPose, pts: StereoPoints) -> np.ndarray:
    parts = run_to_end(pipe.world_parts_steps(placed, pts))
    return np.concatenate([p[0] for p in parts])


def _past_and_high(xyz: np.ndarray) -> int:
    """Points over the hidden face (0.015 < -y < 0.27 m) at about the plateau's height."""
    return int(np.count_nonzero((xyz[:, 1] < -0.015) & (xyz[:, 1] > -0.27) & (xyz[:, 2] > -0.1)))


def _knows_the_lip(pipe: SensingPipeline) -> None:
    """A first, accurate view of the plateau (y > 0) finds the lip at y = 0 with the ground 1 m
    below behind it; its points go into the map."""
    lx = np.linspace(-1.0, 1.0, 200)
    near = np.column_stack([lx, np.zeros(200), np.zeros(200)])
    far = np.column_stack([lx, np.full(200, -1.3), np.full(200, -1.0)])
    placed, pts = _view(_plateau(30000, 0.0, 1.2, 0.0, 1), 0.002, near, far)
    _seed(pipe, _merged_points(pipe, placed, pts))
    pipe.remember_lips(placed, pts)


def test_a_view_without_lips_places_nothing_past_a_lip_an_earlier_view_found(cfg: FswConfig) -> None:
    """A later view 15 cm off towards the drop, finding no lip of its own, keeps its plateau
    heights off the hidden face, and the rest of the plateau."""
    pipe = SensingPipeline(cfg, None)
    _knows_the_lip(pipe)
    assert pipe.lips.cells > 50
    shifted = _plateau(12000, 0.0, 1.2, 0.0, 3) - [0.0, 0.15, 0.0]
    placed, pts = _view(shifted, sigma_xy=0.1)
    kept = _merged_points(pipe, placed, pts)
    assert _past_and_high(shifted) > 1000  # what the view would put there
    assert _past_and_high(kept) == 0
    assert kept.shape[0] > 0.8 * shifted.shape[0]
    # withheld only within 2 sigma past the lip (y = 0)
    gone = shifted[~np.isin(np.round(shifted[:, 1], 9), np.round(kept[:, 1], 9))]  # through the camera and back
    assert np.all(gone[:, 1] <= 1e-9) and np.all(gone[:, 1] >= -0.2 - 1e-9)
    # the lips are kept with the map's state and gone with a new survey
    again = KnownLips(pipe.map.grid)
    again.restore(pipe.lips.state())
    np.testing.assert_array_equal(again.var, pipe.lips.var)
    np.testing.assert_array_equal(again.xyz, pipe.lips.xyz)
    pipe.clear()
    assert pipe.lips.cells == 0


def test_the_lips_heights_turn_with_the_levelled_map(cfg: FswConfig) -> None:
    lips = KnownLips(SensingPipeline(cfg, None).map.grid)
    lips.add(np.array([[1.0, 0.5, 0.2], [-1.0, -0.5, 0.2]]), np.array([[0.0, -1.0], [0.0, -1.0]]), np.zeros(2))
    lips.relevel(np.array([0.01, -0.02]), np.array([0.0, 0.0, 1.0]))
    z = lips.xyz[..., 2][np.isfinite(lips.var)]
    np.testing.assert_allclose(np.sort(z), np.sort([0.2 + 0.01 * 0.5 + 0.02 * 1.0, 0.2 - 0.01 * 0.5 - 0.02 * 1.0]))


def test_ground_below_a_known_lip_and_the_plateau_before_it_are_kept(cfg: FswConfig) -> None:
    """Past the lip, points more than the lip's min drop below it are ground below it, whatever
    their horizontal error; points on the plateau side are plateau."""
    pipe = SensingPipeline(cfg, None)
    _knows_the_lip(pipe)
    face = _plateau(3000, -0.25, -0.02, -0.6, 4)  # below the lip, 0.6 m down
    plateau = _plateau(3000, 0.0, 1.2, 0.0, 5)
    placed, pts = _view(np.concatenate([face, plateau]), sigma_xy=0.1)
    assert _merged_points(pipe, placed, pts).shape[0] == 6000


def test_a_badly_placed_lip_guards_as_far_as_its_own_sigma_reaches(cfg: FswConfig) -> None:
    """A lip's own horizontal variance adds to the view's: an accurate view is guarded past a
    lip placed with a 10 cm sigma, and within 2 sigma of both only."""
    pipe = SensingPipeline(cfg, None)
    pipe.lips.add(np.array([[0.0, 0.0, 0.0]]), np.array([[0.0, -1.0]]), np.array([0.1**2]))
    pts_w = np.array([[0.0, -0.15, 0.0], [0.0, -0.25, 0.0], [0.0, -0.15, -0.5], [0.0, 0.15, 0.0]])
    placed, pts = _view(pts_w, sigma_xy=0.001)
    kept = _merged_points(pipe, placed, pts)
    np.testing.assert_allclose(np.sort(kept[:, 1]), [-0.25, -0.15, 0.15], atol=1e-9)


def test_a_broken_lips_state_restores_no_lips(cfg: FswConfig) -> None:
    lips = KnownLips(SensingPipeline(cfg, None).map.grid)
    for bad in ({}, {"cells": "??", "lips": ""}, {"cells": 3, "lips": None}):
        lips.restore(bad)
        assert lips.cells == 0


def test_a_lip_cell_seen_from_below_keeps_the_lips_height_not_the_faces(cfg: FswConfig) -> None:
    """A view from below the lip (the Cliff-bot's, on the face) puts the face under the lip into
    the gravity grid's lip cell, and, by its error along its sight lines, behind the lip into the
    plateau's cells: the lip's cell keeps the lip's height, the plateau's cell stays unknown, the
    face below keeps the face's heights and the plateau beyond the points' reach is not guarded."""
    pipe = SensingPipeline(cfg, None)
    pipe.lips.add(np.array([[0.0, 0.015, 0.0]]), np.array([[0.0, -1.0]]), np.zeros(1))  # lip cell: 0 <= y < 0.03
    rng = np.random.default_rng(6)

    def at(n: int, y0: float, y1: float, z: float) -> np.ndarray:
        return np.column_stack([rng.uniform(0.001, 0.029, n), rng.uniform(y0, y1, n), np.full(n, z)])

    rim = at(20, 0.016, 0.029, 0.0)  # the lip itself, seen from below
    under = at(20, 0.001, 0.014, -1.0)  # the face under it, in the lip's cell
    behind = at(20, 0.061, 0.089, -1.2)  # the face carried behind the lip by the points' error
    face = at(20, -0.29, -0.21, -1.0)  # the face below the lip
    far = at(20, 0.61, 0.69, -1.2)  # a hollow in the plateau, out of the points' reach of the lip
    placed, pts = _view(np.concatenate([rim, under, behind, face, far]), sigma_xy=0.05)
    parts = run_to_end(pipe.world_parts_steps(placed, pts))
    run_to_end(pipe.fuse_steps(placed, parts))
    m, g = pipe.map, pipe.map.grid

    def cell(y: float) -> tuple[int, int]:
        iy, ix, _ = g.cell_index(np.array([0.015]), np.array([y]))
        return int(iy[0]), int(ix[0])

    assert abs(m.z[cell(0.02)]) < 0.01  # the lip's height, not the mean with the face's
    assert not m.mapped[cell(0.075)]
    assert m.z[cell(-0.25)] == pytest.approx(-1.0, abs=0.01)
    assert m.z[cell(0.65)] == pytest.approx(-1.2, abs=0.01)
    # the guard off (lip_guard_sigma 0) takes them all
    off = dataclasses.replace(cfg, fusion=dataclasses.replace(cfg.fusion, lip_guard_sigma=0.0))
    pipe = SensingPipeline(off, None)
    pipe.lips.add(np.array([[0.0, 0.015, 0.0]]), np.array([[0.0, -1.0]]), np.zeros(1))
    run_to_end(pipe.fuse_steps(placed, run_to_end(pipe.world_parts_steps(placed, pts))))
    assert pipe.map.z[cell(0.02)] < -0.4 and pipe.map.mapped[cell(0.075)]



def _withheld_from(cfg: FswConfig, eye: np.ndarray, pts_w: np.ndarray, sigma_m: float,
                   sight_line: bool = True) -> np.ndarray:
    """Which of ``pts_w`` a view from a camera at ``eye`` withholds past the known lip along
    ``y = 0``, ``z = 0`` (drop side -y), the camera's place known to ``sigma_m`` (``sight_line``:
    ``[fusion] lip_sight_line``)."""
    pipe = SensingPipeline(dataclasses.replace(cfg, fusion=dataclasses.replace(cfg.fusion, lip_sight_line=sight_line)),
                           None)
    lx = np.arange(-0.3, 0.31, CELL)
    pipe.lips.add(np.column_stack([lx, np.zeros_like(lx), np.zeros_like(lx)]),
                  np.tile([0.0, -1.0], (lx.size, 1)), np.zeros(lx.size))
    camera = CameraPose(np.eye(3), eye)
    n = pts_w.shape[0]
    pts = StereoPoints(camera.world_to_camera(pts_w), np.tile(np.eye(3) * 1e-6, (n, 1, 1)), np.zeros((n, 2)),
                       np.ones(n), np.ones((1, n), bool))
    cov = np.zeros((6, 6))
    cov[3, 3] = cov[4, 4] = cov[5, 5] = sigma_m**2
    kept = _merged_points(pipe, RegisteredPose(Registration("off", "test"), camera, cov, None), pts)
    return ~np.isin(pts_w[:, 0], kept[:, 0])


def test_a_known_lip_withholds_only_what_it_can_hide_from_that_camera(cfg: FswConfig) -> None:
    """The face just under a known lip (past it, less than the lip's min drop below it, within the
    guard's reach of it): from a camera on the plateau behind the lip, whose sight lines to it
    pass under the lip, it is withheld (the lip hides that ground: such a point was carried over
    the edge); from a camera beyond the lip looking back down at the face, no lip stands in the
    way and it is kept (docs/algorithm.md §4)."""
    face = np.column_stack([np.linspace(-0.2, 0.2, 5), np.linspace(-0.035, -0.045, 5), np.linspace(-0.1, -0.2, 5)])
    assert _withheld_from(cfg, np.array([0.0, 3.0, 0.8]), face, sigma_m=0.03).all()
    assert not _withheld_from(cfg, np.array([0.0, -0.3, 0.45]), face, sigma_m=0.03).any()
    # a sight line over the lip within the reach (a camera behind it looking down past it) is withheld
    assert _withheld_from(cfg, np.array([0.0, 0.3, 1.5]), face, sigma_m=0.03).all()
    # lip_sight_line off (the RECON-bot's views): every point near the lip past it, from any camera
    assert _withheld_from(cfg, np.array([0.0, -0.3, 0.45]), face, sigma_m=0.03, sight_line=False).all()
