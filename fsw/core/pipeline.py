"""The sensing pipeline: one stereo view into the map (docs/algorithm.md §4), the one implementation the
flight, the benches, the replays and the tests all run.

rectify (``fsw.core.stereo.rectify``, when the camera has a calibration) -> stereo matching and
triangulation with covariance (``fsw.core.stereo.stereo``, §1.2) -> registration of the view
against the map (§5.1, ``fsw.core.registration``: the pose corrected, or its covariance inflated
when it cannot be registered; the station chain) -> world points with covariance (stereo, pose
and the calibration's disparity offset, §1.2), the occluding-lip guard
(``fsw.core.stereo.occlusion``) -> fusion into the map with the misses of the cells the view was
expected to see (P_V on the map before the merge, §1.1, §3.1, §3.4) -> the edge: edge cells, the
non-convex polygon fit and the mapped fraction of the region of interest (§2, §3.6).

:meth:`SensingPipeline.view_steps` is a step generator (``fsw.core.steps``): every stage yields
between bounded slices (SGBM and remap in row bands, triangulation, propagation and both merge
passes in point chunks, P_V in ray chunks, the edge search in halves), so the perception task
runs it as a slack job; benches, replays and tests run the same generator to its end
(:meth:`SensingPipeline.view`; :meth:`SensingPipeline.merge_view` stops before the edge). Its
stages are methods of their own (:meth:`SensingPipeline.register_steps`, ``world_parts_steps``,
``fuse_steps``) for the tests that feed one stage directly. An optional ``stage`` callback is
told where each stage starts (:data:`STAGES`), so a bench times what flies.
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from fsw.core.edge.edge import EdgeCells, EdgeConfig, EdgeModel, edge_cells_steps, fit_polygon_steps
from fsw.core.edge.roi import roi_mapped_fraction_steps
from fsw.core.geometry import CameraConfig, CameraPose, MapGrid, MapGridConfig
from fsw.core.localization.localization import point_covariance_parts
from fsw.core.localization.nav_fix import NavFix
from fsw.core.map.body_mask import MaskConfig, TeamGeometry, team_mask
from fsw.core.map.elevation_map import ElevationMap, FusionConfig, MergeStats
from fsw.core.map.face_map import FaceMap, split_parts
from fsw.core.map.known_lips import KnownLips, horizontal_variance
from fsw.core.map.reference_frames import ReferenceFrames
from fsw.core.planning.nbv import NbvConfig, predicted_visibility_steps
from fsw.core.registration.mount_bias import Levelling, MountBias, data_only
from fsw.core.registration.registration import (
    Registration,
    RegistrationConfig,
    apply_correction,
    reference_cells,
    register_steps,
)
from fsw.core.registration.station_chain import StationChain, apply_about
from fsw.core.steps import run_to_end
from fsw.core.stereo.occlusion import LipGuard
from fsw.core.stereo.rectify import Rectifier
from fsw.core.stereo.rig_drift import RigAlignment
from fsw.core.stereo.stereo import StereoConfig, StereoMatcher, StereoPoints
from fsw.core.stereo.stereo_calibration import StereoCalibration, offset_covariance

F64 = NDArray[np.float64]
ViewPart = tuple[F64, F64, F64 | None]  # world xyz, total covariance, the view's common (pose) covariance
PROPAGATE_CHUNK = 10000  # points per slice of the covariance propagation (~5 ms on the lab's machine)
MERGE_STEP_POINTS = 50000  # points per slice of each pass of the map merge (a few ms)
STAGES = ("rectify", "stereo", "register", "merge", "edge")  # what the ``stage`` callback is told


class PipelineSettings(Protocol):
    """The configuration sections the pipeline reads (``fsw.settings.FswConfig`` has them)."""

    @property
    def camera(self) -> CameraConfig: ...
    @property
    def stereo(self) -> StereoConfig: ...
    @property
    def map(self) -> MapGridConfig: ...
    @property
    def fusion(self) -> FusionConfig: ...
    @property
    def registration(self) -> RegistrationConfig: ...
    @property
    def nbv(self) -> NbvConfig: ...
    @property
    def edge(self) -> EdgeConfig: ...


class StereoView(Protocol):
    """One captured pair with its camera pose estimate (``fsw.tasks.messages.CameraFrame`` is one)."""

    @property
    def view_id(self) -> int: ...
    @property
    def time_s(self) -> float: ...
    @property
    def left(self) -> NDArray[np.uint8]: ...
    @property
    def right(self) -> NDArray[np.uint8]: ...
    @property
    def pose(self) -> CameraPose: ...  # the estimate at capture (left camera, world frame)
    @property
    def pose_cov(self) -> F64: ...  # 6x6, rotation vector (rad) then translation (m)
    @property
    def ground_z_m(self) -> float: ...  # the ground under the rover at capture
    @property
    def nav_fix_id(self) -> int: ...  # the navigation fix the pose holds
    @property
    def body_yaw_rad(self) -> float: ...  # the rover's yaw at capture (NaN: unknown; the mount biases need it)


@dataclass(frozen=True)
class RegisteredPose:
    """A view's pose after registration (§5.1): the pose and covariance its points are merged
    with, and the navigation fix to feed back (None unless registered)."""

    registration: Registration
    pose: CameraPose
    cov: F64
    nav_fix: NavFix | None


@dataclass(frozen=True)
class MergedView:
    """What one view did to the map: its registration and the merge."""

    placed: RegisteredPose
    merge: MergeStats
    view_cells: tuple[NDArray[np.int32], NDArray[np.float32]]  # flat cell index, mean height (m)
    alignment: RigAlignment = field(default_factory=RigAlignment.none)  # the rig-drift correction (§4)
    levelling: Levelling | None = None  # the map's frame levelled after this view (mount biases, §5.1)


@dataclass(frozen=True)
class SensedView:
    """What one view did: its registration, the merge, the edge fit after it."""

    view_id: int
    placed: RegisteredPose
    merge: MergeStats
    view_cells: tuple[NDArray[np.int32], NDArray[np.float32]]  # flat cell index, mean height (m)
    edge_cells: EdgeCells
    edge: EdgeModel
    roi_mapped_fraction: float
    alignment: RigAlignment = field(default_factory=RigAlignment.none)  # the rig-drift correction (§4)
    levelling: Levelling | None = None  # the map's frame levelled after this view (mount biases, §5.1)


def _no_stage(name: str) -> None:
    """The default ``stage`` callback: nothing to time."""


class SensingPipeline:
    """The map, the registration state (station chain, each cell's source view) and the camera
    model (rectification maps built once, the matcher) of one survey, and the view -> map step.

    ``calibration``: the camera's stereo calibration (``fsw.settings.load_stereo_calibration``;
    None: the pairs are rectified already); ``emap``: the map to merge into (default an empty
    one on ``cfg.map``)."""

    def __init__(self, cfg: PipelineSettings, calibration: StereoCalibration | None,
                 emap: ElevationMap | None = None) -> None:
        self.cfg = cfg
        # rectified onto the configured pinhole camera, so P_V and the planner see the same one
        self.rectifier = None if calibration is None else Rectifier(calibration, cfg.camera.K)
        self.matcher = StereoMatcher(cfg.stereo, cfg.camera, None if self.rectifier is None else self.rectifier.camera)
        self.map = ElevationMap(MapGrid.from_config(cfg.map), cfg.fusion) if emap is None else emap
        self.chain = StationChain()  # the registered stations (fsw.core.registration.station_chain)
        self.sources = ReferenceFrames(self.map.grid.shape)  # each cell's view (fsw.core.map.reference_frames)
        self.lips = KnownLips(self.map.grid)  # the lips the views found (fsw.core.map.known_lips)
        r = cfg.registration  # the mast tilt offset and attitude biases (fsw.core.registration.mount_bias)
        self.bias = MountBias(r.bias_tilt_sigma_deg, r.bias_attitude_sigma_deg, r.bias_floor_deg, r.bias_gate_chi2,
                              r.bias_apply_ratio, r.bias_min_step_deg, r.bias_level_chi2, r.bias_drop_variance)
        # The team (docs/algorithm.md §8.1): the face map beside the gravity grid (None: one grid)
        # and the robots and tethers at their known poses, masked out of every view (None: none).
        self.face: FaceMap | None = None
        self.team: TeamGeometry | None = None
        # True: the team's geometry is placed from the same estimate as the camera (the Cliff-bot's
        # own body and tethers): the pose's error moves both alike, and the mask grows by the
        # points' stereo covariance only
        self.team_with_camera = False
        self.team_mask_cfg: MaskConfig | None = None  # the mask's margins (None: MaskConfig's)

    def clear(self) -> None:
        """Forget the map and the registration state (a new survey)."""
        self.map = ElevationMap(self.map.grid, self.cfg.fusion)
        self.chain.clear()
        self.sources.clear()
        self.lips.clear()
        self.bias.clear()

    def view(self, view: StereoView) -> SensedView:
        """:meth:`view_steps` run to its end (benches, replays, tests)."""
        return run_to_end(self.view_steps(view))

    def merge_view(self, view: StereoView) -> MergedView:
        """:meth:`merge_view_steps` run to its end (benches and tests that need no edge fit)."""
        return run_to_end(self.merge_view_steps(view))

    def view_steps(self, view: StereoView, stage: Callable[[str], None] = _no_stage
                   ) -> Generator[None, None, SensedView]:
        """One view into the map and the edge fitted again, a bounded step per slice; ``stage``
        is called with each stage's name (:data:`STAGES`) as it starts."""
        merged = yield from self.merge_view_steps(view, stage)
        stage("edge")
        here = (float(view.pose.t[0]), float(view.pose.t[1]))  # the camera stands over the plateau
        # The ground under the rover now (not at the start: on a slope the rover has climbed or
        # descended since), with the registration's height correction (§2, §5.1).
        ground_z = view.ground_z_m + float(merged.placed.pose.t[2] - view.pose.t[2])
        cells = yield from edge_cells_steps(self.map, ground_z, here, self.cfg.edge)
        yield
        poly = yield from fit_polygon_steps(self.map, cells, self.cfg.edge)
        yield
        roi_fraction = yield from roi_mapped_fraction_steps(self.map, poly)
        yield
        return SensedView(view.view_id, merged.placed, merged.merge, merged.view_cells, cells, poly, roi_fraction,
                          merged.alignment, merged.levelling)

    def merge_view_steps(self, view: StereoView, stage: Callable[[str], None] = _no_stage
                         ) -> Generator[None, None, MergedView]:
        """The view into the map: rectify, stereo, register, world points, fuse (a bounded
        step per slice; ``stage`` as in :meth:`view_steps`)."""
        cfg = self.cfg
        stage("rectify")
        left, right = view.left, view.right
        if self.rectifier is not None:
            left, right = yield from self.rectifier.rectify_steps(left, right, cfg.stereo.band_rows_px)
        stage("stereo")
        dm = yield from self.matcher.match_steps(left, right)
        yield
        pts = yield from self.matcher.triangulate_steps(dm.disparity_px, sigma_px=dm.sigma_px)
        alignment = dm.alignment
        del dm, left, right  # not needed past here: a smaller resident peak (issue 15)
        stage("register")
        placed = yield from self.register_steps(view, pts)
        stage("merge")
        parts = yield from self.world_parts_steps(placed, pts)
        self.remember_lips(placed, pts)  # the view's lips guard the views after it
        del pts  # the camera-frame points: every use is above
        # Which cells this view was expected to see (P_V on the map before the merge, §3.1):
        # those that get no point count a miss and lose interest (§3.4, §4). Only those need
        # P_V: the cells the view's points fall in are not rated (with a face map, which takes
        # some points away from the grid, every cell in view is).
        p_visible = None
        if self.map.mapped.any():
            hit = self.map.hit_cells(parts) if self.face is None else None
            p_visible = yield from predicted_visibility_steps(self.map, view.pose, cfg.camera, cfg.nbv.visibility,
                                                              skip=hit)
            yield
        merged = yield from self.fuse_steps(placed, parts, p_visible)
        merged = replace(merged, alignment=alignment)
        if cfg.registration.enabled and cfg.registration.bias_estimate and self.face is None:
            lev = self.bias.level(self.map)
            if lev is not None:  # the view's own pose moves with the map it is in
                self.chain.relevel(lev.omega, lev.centre)
                self.lips.relevel(lev.omega, lev.centre)
                moved = apply_about(placed.pose, lev.omega, lev.centre)
                merged = replace(merged, placed=replace(placed, pose=moved), levelling=lev)
            yield
        return merged

    def register_steps(self, view: StereoView, pts: StereoPoints) -> Generator[None, None, RegisteredPose]:
        """Align the view to the map (§5.1): the corrected pose, the covariance to merge with
        and the navigation fix to feed back (``fsw.core.registration.station_chain``: where the
        fit starts, the frame error, the feedback)."""
        rcfg = self.cfg.registration
        if not rcfg.enabled:
            return RegisteredPose(Registration("off", "disabled in config"), view.pose, view.pose_cov, None)
        vp = self.chain.prior(view.pose, view.pose_cov, view.nav_fix_id, rcfg)
        use_bias = rcfg.bias_estimate and self.face is None
        tilt = self.bias.predicted(view.pose, view.body_yaw_rad) if use_bias else None
        if tilt is not None:  # the mount biases known: the view starts from their tilt (§5.1)
            vp = replace(vp, d0=np.r_[tilt, vp.d0[2:]])
        prior = apply_correction(view.pose, vp.d0)
        n = len(pts)
        sel = np.linspace(0, n - 1, min(n, 4 * rcfg.max_points)).astype(np.intp) if n else np.zeros(0, np.intp)
        xyz_w, cov_w, _ = point_covariance_parts(prior, None, pts.xyz_c[sel], pts.cov_c[sel])
        ref = reference_cells(self.map.z, self.map.var, self.map.n, rcfg)
        yield
        reg = yield from register_steps(xyz_w, cov_w, prior, vp.cov, self.map.grid, self.map.z,
                                        self.map.var, ref, rcfg, self.sources if rcfg.reference_error else None)
        if reg.status == "reference":
            self.chain.reference(view.pose_cov)
            if use_bias:
                self.bias.reference(view.pose, view.body_yaw_rad, view.pose_cov)
            return RegisteredPose(reg, view.pose, view.pose_cov, None)
        if reg.status != "registered":
            pose, cov = self.chain.unregistered(view.pose, vp, reg, rcfg)
            return RegisteredPose(reg, pose, cov, None)
        pose, cov, nav = self.chain.registered(view.pose, view.pose_cov, view.nav_fix_id, view.time_s, vp, reg, rcfg)
        data = data_only(reg.correction[:2] - vp.d0[:2], (reg.cov - reg.ref_cov)[:2, :2], vp.cov[:2, :2])
        if use_bias and data is not None:  # the total tilt correction the data give, relative to the map
            self.bias.update(view.pose, view.body_yaw_rad, vp.d0[:2] + data[0], data[1])
        return RegisteredPose(reg, pose, cov, nav)

    def world_parts_steps(self, placed: RegisteredPose, pts: StereoPoints) -> Generator[None, None, list[ViewPart]]:
        """The view's points in the world with their covariance (§1.2), in ``PROPAGATE_CHUNK``
        slices: the stereo part per point; the pose part and the calibration's disparity offset
        common to the whole view (it must not average down in a cell); the points too near one
        of the view's own occluding lips for that common error withheld, and those past a lip the
        map knows (the lips earlier views found: ``fsw.core.map.known_lips``)."""
        fus = self.cfg.fusion
        off_sigma = 0.0 if self.rectifier is None else self.rectifier.camera.offset_sigma_px
        lips = LipGuard.of_view(self.map.grid, placed.pose, pts.lip_near_c, pts.lip_far_c, fus.lip_min_drop_m)
        known = self.lips.guard(fus.lip_min_drop_m)
        pose_cov = placed.cov if np.any(placed.cov) else None  # an exact pose (a bench's true one): no pose part
        eye = placed.pose.t if fus.lip_sight_line else None  # only lips that can hide a point withhold it (§4)
        yield
        parts: list[ViewPart] = []
        for a in range(0, len(pts), PROPAGATE_CHUNK):
            b = a + PROPAGATE_CHUNK
            xyz, cov_s, cov_p = point_covariance_parts(placed.pose, pose_cov, pts.xyz_c[a:b], pts.cov_c[a:b])
            if off_sigma > 0.0:
                cal = offset_covariance(xyz, placed.pose.t, pts.disparity_px[a:b], off_sigma)
                cov_p = cal if cov_p is None else cov_p + cal
            if self.team is not None:
                cov_m = cov_s if cov_p is None or self.team_with_camera else cov_s + cov_p
                off = ~team_mask(xyz, cov_m, self.team, self.team_mask_cfg, eye=placed.pose.t)
                xyz, cov_s, cov_p = xyz[off], cov_s[off], None if cov_p is None else cov_p[off]
            parts.append(lips.part(xyz, cov_s, cov_p, fus.lip_guard_sigma, known, eye=eye))
            yield
        return parts

    def remember_lips(self, placed: RegisteredPose, pts: StereoPoints) -> None:
        """The view's counted lips join the lips the map knows (``fsw.core.map.known_lips``), each
        with its horizontal variance from the view's pose (§1.2): how well the map knows where it is."""
        lips = LipGuard.of_view(self.map.grid, placed.pose, pts.lip_near_c, pts.lip_far_c,
                                self.cfg.fusion.lip_min_drop_m)
        n = lips.near.shape[0]
        pose_cov = placed.cov if np.any(placed.cov) else None
        _, _, cov_p = point_covariance_parts(placed.pose, pose_cov, placed.pose.world_to_camera(lips.near),
                                             np.zeros((n, 3, 3)))
        self.lips.add(lips.near, lips.toward, np.zeros(n) if cov_p is None else horizontal_variance(cov_p))

    def fuse_steps(self, placed: RegisteredPose, parts: list[ViewPart],
                   p_visible: NDArray[np.float32] | NDArray[np.float64] | NDArray[np.bool_] | None = None
                   ) -> Generator[None, None, MergedView]:
        """Fuse a view's world points (:meth:`world_parts_steps`, consumed) into the map with
        the misses of the cells in ``p_visible`` that get none (§1.1, §3.4); each cell the view
        measured remembers the view as its source (``fsw.core.map.reference_frames``). With a
        face map the points are split by its hand-over (§8.1) and its share fused there. The
        points under a lip the map knows (its own lips included) stay out of the gravity grid
        (§4, the lip guard: the lip's cell keeps the lip's height, not the face's under it)."""
        if self.face is not None:
            view = parts  # every point's sight line is free space (the face map's overhang test)
            to_face, parts = split_parts(parts, self.face)
            self.face.merge_parts(to_face, eye=placed.pose.t, rays=view, window_rad=self.matcher.window_rad,
                                  max_range_m=self.cfg.camera.max_range_m)
            yield
        known = self.lips.guard(self.cfg.fusion.lip_min_drop_m)
        if known is not None:
            parts = known.gravity_parts(parts, self.cfg.fusion.lip_guard_sigma)
        view_cells = self.map.grid.cell_means(np.concatenate([p[0] for p in parts]) if parts else np.zeros((0, 3)))
        X, Y = (c.reshape(-1)[view_cells[0]] for c in self.map.grid.centers())
        self.sources.add(view_cells[0], np.column_stack([X, Y, view_cells[1]]), placed.pose.t, placed.cov)
        yield
        stats = yield from self.map.merge_parts_steps(parts, p_visible=p_visible, step_points=MERGE_STEP_POINTS,
                                                      eye=placed.pose.t)
        yield
        return MergedView(placed, stats, view_cells)
