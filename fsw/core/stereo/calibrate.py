"""Stereo calibration from views of a planar target (docs/algorithm.md §4: the pair SGBM needs).

The target is a ChArUco board (a chessboard whose white squares carry ArUco markers, so a
partly seen board still gives identified corners) or a plain chessboard, described in
``[calibration]`` of config/fsw.toml. For each stereo pair the corners are found in both
images (``cv2.aruco.CharucoDetector`` or ``cv2.findChessboardCornersSB``, both sub-pixel);
then, with OpenCV's model (pinhole ``K``, Brown–Conrady distortion ``k1, k2, p1, p2[, k3]``):

1. each camera alone: ``cv2.calibrateCamera`` on every corner it saw (initial intrinsics);
2. the pair: ``cv2.stereoCalibrateExtended`` on the corners seen by both cameras, refining
   both cameras' intrinsics with the extrinsics ``R, T`` and giving the reprojection RMS of
   each view;
3. outlier views: a view whose RMS (worse camera) exceeds ``max_view_rms_px`` or
   ``outlier_factor`` times the median is dropped and step 2 re-run, until none is, as long
   as ``min_views`` remain;
4. the calibration's own uncertainty where it matters most for range: the disparity offset
   at infinity (the relative yaw and principal points, which targets at 1 m fix poorly),
   its jackknife sigma over the used views (``disparity_offset_sigma_px``; the flight's
   point covariance carries it, ``stereo_calibration.offset_covariance``).

Bad input raises :class:`CalibrationInputError` with one line (the CLI exits 2).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import cv2
import numpy as np
from numpy.typing import NDArray

from fsw.core.stereo.stereo_calibration import StereoCalibration, disparity_offset_px
from fsw.framework.params import param

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]


class CalibrationInputError(ValueError):
    """Views that cannot give a calibration (too few, target not found, sizes differ)."""


@dataclass(frozen=True)
class CalibrationConfig:
    """The calibration target and the outlier rules (config ``[calibration]``)."""

    target: str = param("charuco", choices=("charuco", "chessboard"), doc="target type")
    squares_x: int = param(9, lo=3, hi=40, doc="squares along the board's width")
    squares_y: int = param(7, lo=3, hi=40, doc="squares along the board's height")
    square_m: float = param(0.06, lo=0.001, hi=1.0, units="m", doc="chessboard square side")
    marker_m: float = param(0.045, lo=0.001, hi=1.0, units="m", doc="ArUco marker side (charuco)")
    dictionary: str = param("DICT_5X5_100", doc="cv2.aruco predefined dictionary (charuco)")
    min_views: int = param(8, lo=3, hi=1000, doc="fewest usable views (pairs) for a calibration")
    min_corners: int = param(12, lo=6, hi=10000, doc="fewest corners seen by both cameras in a usable view")
    max_view_rms_px: float = param(1.0, lo=0.01, hi=100.0, units="px", doc="a worse view is an outlier")
    outlier_factor: float = param(3.0, lo=1.0, hi=100.0, doc="... as is one this many times the median RMS")
    fix_k3: bool = param(True, doc="fit k1, k2, p1, p2 only (k3 = 0): lenses under ~60 deg")

    def __post_init__(self) -> None:
        if self.target == "charuco":
            if self.marker_m >= self.square_m:
                raise ValueError("marker_m must be smaller than square_m")
            if not self.dictionary.startswith("DICT_") or not hasattr(cv2.aruco, self.dictionary):
                raise ValueError(f"dictionary {self.dictionary!r} is not a cv2.aruco predefined dictionary")

    def charuco_board(self) -> cv2.aruco.CharucoBoard:
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_m, self.marker_m, d)

    def object_corners(self) -> F32:
        """Inner corners in the board frame ``(N, 3)`` (x right, y down, metres), id order."""
        if self.target == "charuco":
            return np.asarray(self.charuco_board().getChessboardCorners(), np.float32)
        gx, gy = np.meshgrid(np.arange(1, self.squares_x), np.arange(1, self.squares_y))
        xy = np.stack([gx.ravel(), gy.ravel()], axis=-1) * self.square_m
        return np.column_stack([xy, np.zeros(len(xy))]).astype(np.float32)


@dataclass(frozen=True)
class ViewReport:
    name: str
    corners: int  # seen by both cameras (0: target not found in one image)
    rms_left_px: float
    rms_right_px: float
    used: bool
    note: str = ""


@dataclass(frozen=True)
class CalibrationResult:
    calibration: StereoCalibration
    views: tuple[ViewReport, ...]


class TargetDetector:
    """Finds the target's corners (ids and sub-pixel positions) in one grey image."""

    def __init__(self, cfg: CalibrationConfig) -> None:
        self.cfg = cfg
        self.object_corners = cfg.object_corners()
        if cfg.target == "charuco":
            self._det = cv2.aruco.CharucoDetector(cfg.charuco_board())

    def detect(self, image: U8) -> tuple[NDArray[np.int32], F32]:
        """Corner ids ``(N,)`` and pixels ``(N, 2)``; empty when the target is not found."""
        none = (np.zeros(0, np.int32), np.zeros((0, 2), np.float32))
        if self.cfg.target == "charuco":
            corners, ids, _, _ = self._det.detectBoard(image)
            if ids is None or len(ids) == 0:
                return none
            return ids.ravel().astype(np.int32), corners.reshape(-1, 2).astype(np.float32)
        size = (self.cfg.squares_x - 1, self.cfg.squares_y - 1)
        ok, corners = cv2.findChessboardCornersSB(image, size, flags=cv2.CALIB_CB_ACCURACY)
        if not ok:
            return none
        return np.arange(size[0] * size[1], dtype=np.int32), corners.reshape(-1, 2).astype(np.float32)


def calibrate_stereo(pairs: Sequence[tuple[str, U8, U8]], cfg: CalibrationConfig,
                     K_target: F64 | None = None) -> CalibrationResult:
    """Calibrate from named grey pairs ``(name, left, right)`` of the target (module doc);
    ``K_target``: the rectified camera the flight software uses (its disparity offset
    uncertainty is estimated for it; None: OpenCV's rectified ``P1``)."""
    if not pairs:
        raise CalibrationInputError("no image pairs given")
    size = pairs[0][1].shape
    for name, left, right in pairs:
        if left.shape != size or right.shape != size:
            raise CalibrationInputError(
                f"{name}: image sizes differ ({left.shape[1]}x{left.shape[0]} and {right.shape[1]}x"
                f"{right.shape[0]}; the first left image is {size[1]}x{size[0]})")
    det = TargetDetector(cfg)
    obj_all = det.object_corners
    mono: list[list[tuple[F32, F32]]] = [[], []]
    views: list[tuple[str, F32, F32, F32]] = []
    notes: dict[str, tuple[int, str]] = {}
    for name, left, right in pairs:
        found = [det.detect(img) for img in (left, right)]
        for side, (ids, px) in enumerate(found):
            if len(ids) >= cfg.min_corners:
                mono[side].append((obj_all[ids], px))
        common, il, ir = np.intersect1d(found[0][0], found[1][0], return_indices=True)
        if len(common) < cfg.min_corners:
            notes[name] = (len(common), "target not found in both images" if len(common) == 0
                           else f"only {len(common)} corners seen by both cameras")
            continue
        views.append((name, obj_all[common], found[0][1][il], found[1][1][ir]))
    if len(views) < cfg.min_views:
        raise CalibrationInputError(
            f"{len(views)} usable view(s) of the target, at least {cfg.min_views} needed "
            f"({len(pairs) - len(views)} without the target in both images)")
    wh = (size[1], size[0])
    flags = cv2.CALIB_FIX_K3 if cfg.fix_k3 else 0
    Ks: list[F64] = []
    Ds: list[F64] = []
    for side in (0, 1):
        _, K, D, _, _ = cv2.calibrateCamera([o for o, _ in mono[side]], [p for _, p in mono[side]],
                                            wh, np.eye(3), np.zeros(5), flags=flags)
        Ks.append(np.asarray(K, np.float64))
        Ds.append(np.asarray(D, np.float64))
    used = list(range(len(views)))
    while True:
        rms, K1, D1, K2, D2, R, T, per_view = _stereo(views, used, Ks, Ds, wh, flags)
        worst = per_view.max(axis=1)
        limit = min(cfg.max_view_rms_px, cfg.outlier_factor * float(np.median(worst)))
        bad = [used[i] for i in np.flatnonzero(worst > limit)]
        if not bad or len(used) - len(bad) < cfg.min_views:
            break
        for i in bad:
            notes[views[i][0]] = (len(views[i][1]), f"outlier: view RMS {worst[used.index(i)]:.3f} px > {limit:.3f}")
        used = [i for i in used if i not in bad]
    cal = StereoCalibration(wh[0], wh[1], K1, D1.reshape(1, -1)[:, :5], K2, D2.reshape(1, -1)[:, :5], R, T,
                            rms_px=float(rms), views=len(used))
    cal = replace(cal, disparity_offset_sigma_px=_jackknife_offset(cal, views, used, flags, K_target))
    errs = _view_errors(views, cal)
    reports = []
    for name, _, _ in pairs:
        idx = next((i for i, v in enumerate(views) if v[0] == name), None)
        if idx is None:
            n, note = notes.get(name, (0, ""))
            reports.append(ViewReport(name, n, float("nan"), float("nan"), False, note))
        else:
            n, note = notes.get(name, (len(views[idx][1]), ""))
            reports.append(ViewReport(name, n, errs[idx][0], errs[idx][1], idx in used, note))
    return CalibrationResult(cal, tuple(reports))


def _stereo(views: list[tuple[str, F32, F32, F32]], used: list[int], Ks: list[F64], Ds: list[F64],
            wh: tuple[int, int], flags: int) -> tuple[float, F64, F64, F64, F64, F64, F64, F64]:
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    sel = [views[i] for i in used]
    out = cv2.stereoCalibrateExtended(
        [v[1] for v in sel], [v[2] for v in sel], [v[3] for v in sel], Ks[0].copy(), Ds[0].copy(),
        Ks[1].copy(), Ds[1].copy(), wh, np.eye(3), np.zeros((3, 1)),
        flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS, criteria=crit)
    K1, D1, K2, D2, R, T = (np.asarray(m, np.float64) for m in out[1:7])
    per_view = np.asarray(out[-1], np.float64).reshape(len(sel), 2)
    return float(out[0]), K1, D1, K2, D2, R, T.reshape(3, 1), per_view


def _jackknife_offset(cal: StereoCalibration, views: list[tuple[str, F32, F32, F32]], used: list[int], flags: int,
                      K_target: F64 | None) -> float:
    """Jackknife sigma of the disparity offset (at infinity) of ``cal``: the pair refitted
    without each used view in turn (step 4 of the module doc)."""
    K = cal.rectification()[2][:, :3] if K_target is None else np.asarray(K_target, np.float64)
    wh = (cal.width_px, cal.height_px)
    offs = []
    for i in used:
        _, K1, D1, K2, D2, R, T, _ = _stereo(views, [j for j in used if j != i], [cal.K1, cal.K2],
                                             [cal.D1, cal.D2], wh, flags)
        other = StereoCalibration(wh[0], wh[1], K1, D1.reshape(1, -1)[:, :5], K2, D2.reshape(1, -1)[:, :5], R, T)
        offs.append(disparity_offset_px(cal, other, K))
    n = len(offs)
    a = np.asarray(offs)
    return float(np.sqrt((n - 1) / n * np.sum((a - a.mean()) ** 2))) if n > 1 else 0.0


def _view_errors(views: list[tuple[str, F32, F32, F32]], cal: StereoCalibration) -> list[tuple[float, float]]:
    """Reprojection RMS of each view in each camera (the board pose by PnP in the left
    camera, carried to the right one by ``R, T``), px."""
    out = []
    for _, obj, pl, pr in views:
        ok, rvec, tvec = cv2.solvePnP(obj, pl, cal.K1, cal.D1, flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            out.append((float("nan"), float("nan")))
            continue
        Rb = cv2.Rodrigues(rvec)[0]
        rvec_r = cv2.Rodrigues(cal.R @ Rb)[0]
        tvec_r = cal.R @ tvec + cal.T
        el = cv2.projectPoints(obj, rvec, tvec, cal.K1, cal.D1)[0].reshape(-1, 2) - pl
        er = cv2.projectPoints(obj, rvec_r, tvec_r, cal.K2, cal.D2)[0].reshape(-1, 2) - pr
        out.append((float(np.sqrt((el**2).sum(1).mean())), float(np.sqrt((er**2).sum(1).mean()))))
    return out
