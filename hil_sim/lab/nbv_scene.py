"""Map states for next-view tests and ``safer-hil bench nbv`` (docs/algorithm.md §3, §7).

* :func:`synthetic_terrain`: a small lab-like truth on a map grid (step edge along +x with a
  wiggle, plateau z = 0 at larger y, recessed pit, three rock mounds, a textureless patch).
* :func:`lab_truth`: the same arrays from the world engineer's ``lab`` scenario.
* :func:`simulated_view`: an idealised stereo view merged into an ``ElevationMap``: every
  textured cell that the true terrain lets the camera see (true ``P_V > 0.5``) inside the
  view gets one point at the true height plus stereo noise ``Z^2 sigma_d / (f B)`` (§1.2).
  It bypasses rendering and stereo, so tests and benches of the planner stay fast.
* :func:`panorama_map`: the start of the mission (paper Figure 4): a pan sweep from the start.
* :func:`edge_offset_path`: the rover path, the true edge set back into the plateau.
"""

from __future__ import annotations

import math

import numpy as np
from shapely.geometry import LineString

from fsw.core.geometry import CameraConfig, CameraPose, MapGrid, MastConfig, camera_pose_from_rover
from fsw.core.map.elevation_map import ElevationMap, FusionConfig
from fsw.core.planning.nbv import predicted_visibility
from fsw.core.planning.visibility import F64, VisibilityConfig, cell_points, in_view, terrain_from_heights
from fsw.core.planning.visibility_kernel import pv_fast

EDGE_Y_M = -0.8


def synthetic_edge_y(x: F64) -> F64:
    return EDGE_Y_M + 0.15 * np.sin(1.3 * np.asarray(x)) + 0.05 * np.sin(4.1 * np.asarray(x))


def synthetic_terrain(grid: MapGrid, seed: int = 0) -> tuple[F64, np.ndarray]:
    """Truth elevation (ny, nx) and textured mask of a lab-like scene on ``grid``."""
    rng = np.random.default_rng(seed)
    xs, ys = grid.centers()
    pit = ys <= synthetic_edge_y(xs)
    z = np.where(pit, -0.4 + 0.03 * np.sin(2.0 * xs) * np.cos(1.5 * ys), 0.0)
    for rx, ry, rr, rh in ((1.5, -2.5, 0.35, 0.3), (3.5, -3.5, 0.45, 0.35), (5.0, -2.0, 0.3, 0.25)):
        rx, ry = rx + rng.uniform(-0.1, 0.1), ry + rng.uniform(-0.1, 0.1)
        d2 = ((xs - rx) ** 2 + (ys - ry) ** 2) / rr**2
        z = np.maximum(z, np.where(d2 < 1.0, -0.4 + rh * np.sqrt(np.clip(1.0 - d2, 0, 1)), -9.0))
    textured = ~(pit & (np.hypot(xs - 0.6, ys + 2.2) < 0.6))
    return z, textured


def lab_truth(grid: MapGrid, seed: int = 0) -> tuple[F64, np.ndarray, F64]:
    """Truth elevation, textured mask and edge polyline of the ``lab`` scenario on ``grid``."""
    from hil_sim.world import load_scenario

    world = load_scenario("lab", seed=seed)
    z = np.asarray(world.truth_on_grid(grid), dtype=np.float64)
    z = np.where(np.isfinite(z), z, np.nanmin(z))
    textured = ~np.asarray(world.textureless_on_grid(grid), bool)
    return z, textured, np.asarray(world.edge_xy, dtype=np.float64)


def simulated_view(emap: ElevationMap, truth: F64, textured: np.ndarray, pose: CameraPose,
                   camera: CameraConfig, rng: np.random.Generator,
                   vis: VisibilityConfig | None = None, disparity_sigma_px: float = 0.3) -> int:
    """Merge one idealised stereo view into ``emap``; returns the number of cells measured."""
    vis = vis or VisibilityConfig()
    grid = emap.grid
    p_visible = predicted_visibility(emap, pose, camera, vis)
    true_t = terrain_from_heights(truth, grid, 0.005)
    iy, ix = np.nonzero(np.ones(grid.shape, bool))
    pts = cell_points(true_t, iy, ix)
    inv = in_view(pose, camera, pts) & textured[iy, ix]
    iy, ix, pts = iy[inv], ix[inv], pts[inv]
    cam = (float(pose.t[0]), float(pose.t[1]), float(pose.t[2]))
    seen = pv_fast(true_t, cam, iy, ix, vis) > 0.5
    pts = pts[seen]
    depth = pose.world_to_camera(pts)[:, 2]
    sigma = depth**2 * disparity_sigma_px / (camera.focal_px * camera.baseline_m)
    pts[:, 2] += rng.normal(0.0, 1.0, pts.shape[0]) * sigma
    emap.merge(pts, var_z=sigma**2 + 1e-6, p_visible=p_visible)
    return int(pts.shape[0])


def panorama_map(truth: F64, textured: np.ndarray, grid: MapGrid, camera: CameraConfig,
                 mast: MastConfig, rover: tuple[float, float, float], seed: int = 0,
                 pans_deg: tuple[float, ...] = (-150.0, -110.0, -70.0, -30.0, 10.0),
                 tilt_deg: float = -30.0, fusion: FusionConfig | None = None) -> ElevationMap:
    """A map after the start panorama: one view per pan from ``rover`` (lift at maximum)."""
    emap = ElevationMap(grid, fusion or FusionConfig())
    rng = np.random.default_rng(seed)
    for pan in pans_deg:
        pose = camera_pose_from_rover(rover, (math.radians(pan), math.radians(tilt_deg),
                                              mast.lift_max_m), mast)
        simulated_view(emap, truth, textured, pose, camera, rng)
    return emap


def edge_offset_path(edge_xy: F64, setback_m: float, spacing_m: float = 0.25) -> F64:
    """(N, 2) path ``setback_m`` to the left of the edge polyline (the plateau side, +y here)."""
    off = LineString(np.asarray(edge_xy, dtype=np.float64)).offset_curve(setback_m)
    n = max(2, int(off.length / spacing_m) + 1)
    return np.array([off.interpolate(s).coords[0] for s in np.linspace(0, off.length, n)])


def synthetic_edge(x0: float = -0.5, x1: float = 7.0, step_m: float = 0.05) -> F64:
    xs = np.arange(x0, x1 + 1e-9, step_m)
    return np.column_stack([xs, synthetic_edge_y(xs)])
