"""``safer-fsw calibrate``: stereo calibration from image pairs of the target (docs/perception.md).

Reads the pairs ``LEFT_PREFIX*`` / ``RIGHT_PREFIX*`` of a directory (matched by what follows
the prefix, e.g. ``left_07.png`` with ``right_07.png``), finds the target of
``[calibration]`` in each image, calibrates both cameras and the pair
(``fsw.core.stereo.calibrate``), prints the reprojection RMS of every view (and why a view was
not used) and writes the OpenCV FileStorage YAML (``fsw.core.stereo.stereo_calibration``) that
``[camera] calibration_file`` names. Bad input (no or unreadable images, unpaired files,
sizes that differ from each other or from the camera, too few views with the target) is
one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

IMAGE_SUFFIXES = (".png", ".pgm", ".bmp", ".tif", ".tiff", ".jpg", ".jpeg")


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser], default_config: str) -> None:
    c = sub.add_parser(
        "calibrate",
        help="stereo calibration from image pairs of the target; writes an OpenCV YAML",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        description="Calibrate the stereo pair (intrinsics, Brown-Conrady distortion, extrinsics) "
        "from image pairs of the [calibration] target (ChArUco or chessboard) in DIR; print the "
        "reprojection error per view, reject outlier views and write the calibration as an OpenCV "
        "FileStorage YAML. Render pairs on the bench with `safer-hil calibration-target`.",
    )
    c.add_argument("directory", type=Path, metavar="DIR", help="directory with the image pairs")
    c.add_argument("--left-prefix", default="left_", help="file-name prefix of the left images")
    c.add_argument("--right-prefix", default="right_", help="file-name prefix of the right images")
    c.add_argument("--out", type=Path, default=Path("out/stereo_calibration.yaml"), help="calibration file to write")
    c.add_argument("--config", default=default_config, help="flight configuration (TOML): camera size, target")
    c.set_defaults(_run=run)


def _pairs(directory: Path, lp: str, rp: str) -> list[tuple[str, Path, Path]]:
    if not directory.is_dir():
        raise ValueError(f"{directory}: not a directory")
    files = sorted(p for p in directory.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    lefts = {p.stem[len(lp):]: p for p in files if p.name.startswith(lp)}
    rights = {p.stem[len(rp):]: p for p in files if p.name.startswith(rp)}
    if not lefts:
        raise ValueError(f"{directory}: no images named {lp}*")
    unpaired = sorted(set(lefts) ^ set(rights))
    if unpaired:
        raise ValueError(f"{directory}: {len(unpaired)} image(s) without a partner, e.g. {unpaired[0]!r}")
    return [(key, lefts[key], rights[key]) for key in sorted(lefts)]


def run(args: argparse.Namespace) -> int:
    import cv2
    import numpy as np

    from fsw.core.stereo.calibrate import CalibrationInputError, calibrate_stereo
    from fsw.drivers.calibration_file import CalibrationError, save_calibration
    from fsw.framework.params import ConfigError
    from fsw.settings import load_settings

    def fail(msg: str) -> int:
        print(f"safer-fsw calibrate: {msg}", file=sys.stderr)
        return 2

    try:
        cfg = load_settings(args.config, check_calibration=False)  # it makes that file
    except ConfigError as err:
        return fail(f"config error: {err}")
    try:
        names = _pairs(args.directory, args.left_prefix, args.right_prefix)
    except ValueError as err:
        return fail(str(err))
    cam = cfg.camera
    pairs = []
    for key, lpath, rpath in names:
        imgs = []
        for path in (lpath, rpath):
            raw = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            if raw is None:
                return fail(f"{path}: unreadable image")
            img = np.asarray(raw, dtype=np.uint8)
            if img.shape != (cam.height_px, cam.width_px):
                return fail(f"{path}: {img.shape[1]}x{img.shape[0]} image, the camera is "
                            f"{cam.width_px}x{cam.height_px} ([camera] of {args.config})")
            imgs.append(img)
        pairs.append((key, imgs[0], imgs[1]))
    try:
        res = calibrate_stereo(pairs, cfg.calibration, cfg.camera.K)
        save_calibration(args.out, res.calibration)
    except (CalibrationInputError, CalibrationError) as err:
        return fail(str(err))
    except cv2.error as err:
        return fail(f"OpenCV could not calibrate from these views ({str(err).strip().splitlines()[-1]})")
    print(f"{'view':<16} {'corners':>7} {'left px':>8} {'right px':>8}  used")
    for v in res.views:
        print(f"{v.name:<16} {v.corners:>7} {v.rms_left_px:8.3f} {v.rms_right_px:8.3f}  "
              f"{'yes' if v.used else 'NO'} {v.note}")
    cal = res.calibration
    print(f"stereo reprojection RMS {cal.rms_px:.3f} px over {cal.views} of {len(pairs)} views; "
          f"f {cal.K1[0, 0]:.2f} / {cal.K2[0, 0]:.2f} px, baseline {cal.baseline_m * 1e3:.2f} mm, "
          f"k1 {cal.D1[0, 0]:+.4f} / {cal.D2[0, 0]:+.4f}; disparity offset sigma (jackknife) "
          f"{cal.disparity_offset_sigma_px:.3f} px")
    print(f"wrote {args.out}")
    return 0
