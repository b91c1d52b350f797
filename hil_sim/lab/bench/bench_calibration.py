"""``safer-hil bench calibration``: how well the calibration and rectification recover the truth.

Renders ``--views`` pairs of the target with the bench's true cameras (``hil_sim.world.target``),
calibrates from them exactly as ``safer-fsw calibrate`` does (``fsw.core.stereo.calibrate``) and
prints, against the renderer's truth (``hil_sim.camera_model.TrueCameras.truth``):
  * the stereo reprojection RMS and each view's (px), the views rejected;
  * focal lengths (%), principal points (px), distortion, baseline (%), rotation (deg);
  * the vertical disparity of matched features after rectification (px RMS): the target's
    corners detected again in the *rectified* images of ``--holdout`` new pairs (poses not
    used by the calibration), through the flight software's own ``fsw.core.stereo.rectify``;
  * the range error of those corners triangulated through the rectification (the flight
    software's ``f``, ``B``, ``R1``) against their true positions, %;
  * rectification ms per 640x480 pair (two ``cv2.remap`` with ``CV_16SC2`` maps).
Targets (issue 14): RMS <= 0.3 px, vertical disparity <= 0.2 px, focal within 0.5 %,
baseline within 1 %. ``--write FILE`` also writes the calibration (how
config/stereo_calibration.yaml is made: docs/perception.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

HELP = "calibration from rendered target pairs vs the renderer's truth; rectification ms per pair"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from fsw.settings import DEFAULT_CONFIG
    from hil_sim.rig import DEFAULT_HARDWARE

    p.add_argument("--views", type=int, default=18, help="target pairs to calibrate from")
    p.add_argument("--holdout", type=int, default=6, help="new target pairs for the vertical-disparity check")
    p.add_argument("--seed", type=int, default=0, help="seed of the target poses and the sensor noise")
    p.add_argument("--scenario", default="lab", help="world behind the target")
    p.add_argument("--config", default=str(DEFAULT_CONFIG), help="flight configuration (camera, target)")
    p.add_argument("--hardware", default=str(DEFAULT_HARDWARE), help="bench hardware configuration")
    p.add_argument("--repeats", type=int, default=20, help="timed rectifications (median)")
    p.add_argument("--write", type=Path, default=None, metavar="FILE", help="also write the calibration here")


def load_bench(scenario: str, seed: int, config: str, hardware: str) -> tuple[Any, Any, Any, float]:
    """World, flight config, true cameras and the sensor noise of the bench."""
    from fsw.settings import load_settings
    from hil_sim.camera_model import TrueCameras
    from hil_sim.rig import load_hardware
    from hil_sim.world import load_scenario

    cfg = load_settings(config, check_calibration=False)
    hw = load_hardware(hardware)
    world = load_scenario(scenario, seed)
    noise = hw.camera.noise_sigma if hw.camera.noise_sigma >= 0 else float(world.noise_sigma)
    return world, cfg, TrueCameras.from_config(cfg.camera, hw.camera), noise


def vertical_disparity_px(pairs: list[Any], rectifier: Any, detector: Any) -> tuple[float, float, int]:
    """RMS and mean of ``v_left - v_right`` of the target's corners found in both rectified
    images (raw ones if ``rectifier`` is None), and how many corners."""
    import numpy as np

    dv = []
    for _, left, right in pairs:
        rl, rr = (left, right) if rectifier is None else rectifier.rectify(left, right)
        (il, pl), (ir, pr) = detector.detect(rl), detector.detect(rr)
        _, a, b = np.intersect1d(il, ir, return_indices=True)
        dv.append(pl[a, 1] - pr[b, 1])
    d = np.concatenate(dv) if dv else np.zeros(0)
    if d.size == 0:
        return float("nan"), float("nan"), 0
    return float(np.sqrt(np.mean(d**2))), float(np.mean(d)), int(d.size)


def range_error_pct(pairs: list[Any], poses: list[Any], rectifier: Any, detector: Any,
                    cfg: Any) -> tuple[float, float]:
    """Mean and RMS relative range error (%) of the target's corners triangulated from the
    rectified pairs (the flight software's f, B and R1) against their true positions."""
    import numpy as np

    cam = rectifier.camera
    bw, bh = cfg.squares_x * cfg.square_m, cfg.squares_y * cfg.square_m
    errs = []
    for (_, left, right), (R_cb, centre) in zip(pairs, poses, strict=True):
        rl, rr = rectifier.rectify(left, right)
        (il, pl), (ir, pr) = detector.detect(rl), detector.detect(rr)
        ids, a, b = np.intersect1d(il, ir, return_indices=True)
        d = (pl[a, 0] - pr[b, 0]).astype(np.float64)
        z = cam.focal_px * cam.baseline_m / d
        x_rect = np.column_stack([(pl[a, 0] - cam.cx_px) * z / cam.focal_px,
                                  (pl[a, 1] - cam.cy_px) * z / cam.focal_px, z])
        x_left = x_rect @ cam.R_rect
        origin = centre - R_cb[:, 0] * bw / 2 - R_cb[:, 1] * bh / 2
        truth = origin + detector.object_corners[ids].astype(np.float64) @ R_cb.T
        errs.append(np.linalg.norm(x_left, axis=1) / np.linalg.norm(truth, axis=1) - 1)
    e = 100 * np.concatenate(errs)
    return float(e.mean()), float(np.sqrt(np.mean(e**2)))


def run(args: argparse.Namespace) -> int:
    import statistics
    import sys
    import time

    import cv2
    import numpy as np

    from fsw.core.stereo.calibrate import CalibrationInputError, TargetDetector, calibrate_stereo
    from fsw.core.stereo.rectify import Rectifier
    from fsw.drivers.calibration_file import save_calibration
    from fsw.framework.params import ConfigError
    from hil_sim.world.target import render_target_pairs, target_poses

    if args.views < 3 or args.holdout < 1 or args.repeats < 1:
        print("safer-hil bench calibration: --views >= 3, --holdout >= 1, --repeats >= 1", file=sys.stderr)
        return 2
    try:
        world, cfg, cams, noise = load_bench(args.scenario, args.seed, args.config, args.hardware)
    except (ConfigError, ValueError) as err:
        print(f"safer-hil bench calibration: {err}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    pairs = render_target_pairs(world, cfg, cams, args.views, args.seed, noise)
    held = render_target_pairs(world, cfg, cams, args.holdout, args.seed + 1000, noise)
    t_render = time.perf_counter() - t0
    t0 = time.perf_counter()
    try:
        res = calibrate_stereo(pairs, cfg.calibration, cfg.camera.K)
    except CalibrationInputError as err:
        print(f"safer-hil bench calibration: {err}", file=sys.stderr)
        return 2
    t_cal = time.perf_counter() - t0
    cal, truth = res.calibration, cams.truth()
    print(f"{'ideal' if cams.ideal else 'real'} cameras {cams.width_px}x{cams.height_px}, noise {noise:g} grey "
          f"levels, target {cfg.calibration.target} {cfg.calibration.squares_x}x{cfg.calibration.squares_y}; "
          f"{args.views} views rendered in {t_render:.1f} s, calibrated in {t_cal:.1f} s")
    used = [v for v in res.views if v.used]
    print("per-view RMS left/right px: " + ", ".join(f"{v.rms_left_px:.2f}/{v.rms_right_px:.2f}" for v in used))
    for v in res.views:
        if not v.used:
            print(f"  view {v.name} not used: {v.note}")
    figs = {"reprojection RMS": (cal.rms_px, 0.3, "px")}
    for side, K, Kt in (("left", cal.K1, truth.K1), ("right", cal.K2, truth.K2)):
        ferr = 100 * max(abs(K[0, 0] / Kt[0, 0] - 1), abs(K[1, 1] / Kt[1, 1] - 1))
        figs[f"focal error {side}"] = (ferr, 0.5, "%")
        c = K[:2, 2] - Kt[:2, 2]
        print(f"{side:5s} f {K[0, 0]:.2f} {K[1, 1]:.2f} px (true {Kt[0, 0]:.2f}), principal point off by "
              f"({c[0]:+.2f}, {c[1]:+.2f}) px")
    print(f"distortion left  {np.array2string(cal.D1.ravel(), precision=4)}, right "
          f"{np.array2string(cal.D2.ravel(), precision=4)}; true {np.array2string(truth.D1.ravel(), precision=4)}")
    figs["baseline error"] = (100 * abs(cal.baseline_m / truth.baseline_m - 1), 1.0, "%")
    rot_err = np.degrees(np.linalg.norm(cv2.Rodrigues(cal.R @ truth.R.T)[0]))
    print(f"baseline {cal.baseline_m * 1e3:.3f} mm (true {truth.baseline_m * 1e3:.3f}), rotation error "
          f"{rot_err:.3f} deg")
    rect = Rectifier(cal, cfg.camera.K)
    det = TargetDetector(cfg.calibration)
    rms_dv, mean_dv, n_dv = vertical_disparity_px(held, rect, det)
    figs["vertical disparity (held-out)"] = (rms_dv, 0.2, "px RMS")
    rms_fit, _, n_fit = vertical_disparity_px(pairs, rect, det)
    print(f"vertical disparity after rectification: held-out {rms_dv:.3f} px RMS (mean {mean_dv:+.3f}, "
          f"{n_dv} corners in {args.holdout} pairs); calibration pairs {rms_fit:.3f} px RMS ({n_fit} corners)")
    floor_dv, _, _ = vertical_disparity_px(held, Rectifier(truth, cfg.camera.K), det)
    raw_dv, raw_mean, _ = vertical_disparity_px(held, None, det)
    held_poses = target_poses(cfg.calibration, cams, args.holdout, args.seed + 1000)
    rng_est = range_error_pct(held, held_poses, rect, det, cfg.calibration)
    rng_true = range_error_pct(held, held_poses, Rectifier(truth, cfg.camera.K), det, cfg.calibration)
    print(f"  (the same pairs rectified with the TRUE calibration: {floor_dv:.3f} px RMS, the corner detection floor)")
    print(f"  (the same corners in the raw, unrectified held-out pairs: {raw_dv:.3f} px RMS, mean {raw_mean:+.3f})")
    print(f"range of the held-out corners triangulated through the rectification: mean {rng_est[0]:+.3f} %, "
          f"RMS {rng_est[1]:.3f} % (with the TRUE calibration: mean {rng_true[0]:+.3f} %, RMS {rng_true[1]:.3f} %)")
    l0, r0 = held[0][1], held[0][2]
    times = []
    for _ in range(args.repeats + 1):
        t0 = time.perf_counter()
        rect.rectify(l0, r0)
        times.append(1e3 * (time.perf_counter() - t0))
    figs["rectification"] = (statistics.median(times[1:]), 5.0, "ms per pair")
    bad = 0
    for name, (value, limit, unit) in figs.items():
        ok = value <= limit
        bad += not ok
        print(f"{name:32s} {value:8.3f} {unit:12s} target <= {limit:g}  {'ok' if ok else 'FAIL'}")
    if args.write is not None:
        save_calibration(args.write, cal)
        print(f"wrote {args.write}")
    return 0 if bad == 0 else 1
