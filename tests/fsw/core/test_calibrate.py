"""Stereo calibration from rendered target pairs (issue 14, item 1): the estimate recovers
the renderer's truth, outlier views are rejected, and `safer-fsw calibrate` refuses bad
input with one line and exit status 2."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest

from fsw.cli import main as fsw_main
from fsw.core.stereo.calibrate import CalibrationConfig, CalibrationInputError, TargetDetector, calibrate_stereo
from fsw.core.stereo.rectify import Rectifier
from fsw.core.stereo.stereo_calibration import disparity_offset_px, offset_covariance
from fsw.drivers.calibration_file import load_calibration
from fsw.settings import load_settings
from hil_sim.camera_model import TrueCameras
from hil_sim.lab.bench.bench_calibration import vertical_disparity_px
from hil_sim.rig import load_hardware
from hil_sim.world import load_scenario
from hil_sim.world.target import render_target_pairs

VIEWS = 12


@pytest.fixture(scope="module")
def bench() -> tuple[TrueCameras, list, list]:
    cfg = load_settings()
    cams = TrueCameras.from_config(cfg.camera, load_hardware().camera)
    world = load_scenario("lab", 0)
    pairs = render_target_pairs(world, cfg, cams, VIEWS, 0, 2.0)
    held = render_target_pairs(world, cfg, cams, 3, 99, 2.0)
    return cams, pairs, held


@pytest.mark.slow  # the first user of the module's rendered target pairs
def test_calibration_recovers_the_renderer_truth(bench) -> None:  # type: ignore[no-untyped-def]
    cams, pairs, held = bench
    res = calibrate_stereo(pairs, CalibrationConfig())
    cal, truth = res.calibration, cams.truth()
    assert cal.rms_px <= 0.3
    assert all(v.used for v in res.views) and cal.views == VIEWS
    for K, Kt in ((cal.K1, truth.K1), (cal.K2, truth.K2)):
        assert abs(K[0, 0] / Kt[0, 0] - 1) <= 0.005 and abs(K[1, 1] / Kt[1, 1] - 1) <= 0.005
        assert np.abs(K[:2, 2] - Kt[:2, 2]).max() <= 2.0
    assert abs(cal.baseline_m / truth.baseline_m - 1) <= 0.01
    assert abs(cal.D1[0, 0] - truth.D1[0, 0]) <= 0.01
    rot_err_deg = np.degrees(np.linalg.norm(cv2.Rodrigues(cal.R @ truth.R.T)[0]))
    assert rot_err_deg <= 0.1
    # rectified with the estimate, the held-out pairs' corners lie on the same rows
    det = TargetDetector(CalibrationConfig())
    rms_dv, _, n = vertical_disparity_px(held, Rectifier(cal, load_settings().camera.K), det)
    raw_dv, _, _ = vertical_disparity_px(held, None, det)
    floor_dv, _, _ = vertical_disparity_px(held, Rectifier(truth, load_settings().camera.K), det)
    # 12 views here (the bench's 18 give 0.18 px); the true calibration gives about the same:
    # the corner detector's noise and pose-dependent bias (docs/perception.md, Limits)
    assert n > 60 and rms_dv <= 0.3 < 2.0 < raw_dv
    assert abs(rms_dv - floor_dv) <= 0.1


def test_an_outlier_view_is_rejected(bench) -> None:  # type: ignore[no-untyped-def]
    _, pairs, _ = bench
    bad = list(pairs)
    # the right image of view 3 seen with the target 1 px lower: an outlier in the pair
    name, left, right = bad[3]
    bad[3] = (name, left, np.roll(right, 2, axis=0))
    res = calibrate_stereo(bad, CalibrationConfig())
    rejected = [v for v in res.views if not v.used]
    assert [v.name for v in rejected] == [name] and "outlier" in rejected[0].note
    assert res.calibration.rms_px <= 0.3


def test_too_few_views_and_mismatched_sizes_are_refused(bench) -> None:  # type: ignore[no-untyped-def]
    _, pairs, _ = bench
    with pytest.raises(CalibrationInputError, match="usable view"):
        calibrate_stereo(pairs[:3], CalibrationConfig())
    blank = np.full((480, 640), 128, np.uint8)
    with pytest.raises(CalibrationInputError, match="usable view"):
        calibrate_stereo([(str(i), blank, blank) for i in range(10)], CalibrationConfig())
    with pytest.raises(CalibrationInputError, match="sizes differ"):
        calibrate_stereo([("a", pairs[0][1], pairs[0][2][:-2])], CalibrationConfig())
    with pytest.raises(CalibrationInputError, match="no image pairs"):
        calibrate_stereo([], CalibrationConfig())


def _write(directory: Path, pairs: list) -> Path:  # type: ignore[type-arg]
    directory.mkdir(parents=True, exist_ok=True)
    for name, left, right in pairs:
        cv2.imwrite(str(directory / f"left_{name}.png"), left)
        cv2.imwrite(str(directory / f"right_{name}.png"), right)
    return directory


def test_cli_writes_an_opencv_calibration_file(bench, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    _, pairs, _ = bench
    d = _write(tmp_path / "pairs", pairs)
    out = tmp_path / "cal.yaml"
    assert fsw_main(["calibrate", str(d), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "stereo reprojection RMS" in text and text.count(" yes ") == VIEWS
    cal = load_calibration(out, 640, 480)
    fs = cv2.FileStorage(str(out), cv2.FILE_STORAGE_READ)  # plain OpenCV reads it too
    assert fs.getNode("K1").mat().shape == (3, 3) and fs.getNode("Q").mat().shape == (4, 4)
    assert int(fs.getNode("image_width").real()) == 640 and cal.views == VIEWS


@pytest.mark.parametrize("case", ["no_dir", "empty", "unpaired", "unreadable", "wrong_size", "too_few"])
def test_cli_bad_input_is_one_line_and_exit_2(bench, tmp_path: Path, capsys, case: str) -> None:  # type: ignore[no-untyped-def]
    _, pairs, _ = bench
    d = tmp_path / "pairs"
    d.mkdir()
    if case == "no_dir":
        d = tmp_path / "missing"
    elif case == "unpaired":
        _write(d, pairs[:9])
        (d / "right_00.png").unlink()
    elif case == "unreadable":
        _write(d, pairs[:9])
        (d / "left_03.png").write_bytes(b"not a png")
    elif case == "wrong_size":
        _write(d, [(n, cv2.resize(a, (320, 240)), cv2.resize(b, (320, 240))) for n, a, b in pairs[:9]])
    elif case == "too_few":
        _write(d, pairs[:2])
    assert fsw_main(["calibrate", str(d), "--out", str(tmp_path / "c.yaml")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("safer-fsw calibrate: ") and "\n" not in err and "Traceback" not in err
    assert not (tmp_path / "c.yaml").exists()


def test_jackknife_offset_sigma_covers_the_estimates_error(bench) -> None:  # type: ignore[no-untyped-def]
    """The calibration's disparity offset at infinity (what makes far points systematically
    too far or too near) carries a jackknife sigma; the estimate's actual offset against the
    truth lies within 3 of it, here and in the shipped file (18 views)."""
    cams, pairs, _ = bench
    K = load_settings().camera.K
    cal = calibrate_stereo(pairs, CalibrationConfig(), K).calibration
    truth = cams.truth()
    assert 0.01 < cal.disparity_offset_sigma_px < 0.5
    assert abs(disparity_offset_px(cal, truth, K)) <= 3 * cal.disparity_offset_sigma_px
    shipped = load_calibration("config/stereo_calibration.yaml", 640, 480)
    assert shipped.disparity_offset_sigma_px > 0.01
    assert abs(disparity_offset_px(shipped, truth, K)) <= 3 * shipped.disparity_offset_sigma_px


def test_disparity_offset_of_a_turned_right_camera(bench) -> None:  # type: ignore[no-untyped-def]
    """Against itself a calibration has no offset; with the right camera turned by 0.01 deg
    about y, points at infinity get about f * 0.01 deg of disparity (0.12 px; f (1 + x^2) at
    the normalised column x, so 6 % more over the image)."""
    cams, _, _ = bench
    K = load_settings().camera.K
    truth = cams.truth()
    assert abs(disparity_offset_px(truth, truth, K)) < 1e-4
    turned = dataclasses.replace(truth, R=cv2.Rodrigues(np.r_[0.0, np.radians(0.01), 0.0])[0] @ truth.R)
    assert abs(disparity_offset_px(truth, turned, K)) == pytest.approx(K[0, 0] * np.radians(0.01), rel=0.1)


def test_offset_covariance_is_the_range_squared_law() -> None:
    """A disparity offset sigma s moves a point at range Z along its ray by Z^2 s / (f B)."""
    f, B, Z, s = 690.0, 0.15, 4.0, 0.07
    xyz = np.array([[1.0, 2.0, 0.5 + Z]])
    cov = offset_covariance(xyz, np.array([1.0, 2.0, 0.5]), np.array([f * B / Z]), s)
    assert np.sqrt(cov[0, 2, 2]) == pytest.approx(Z**2 * s / (f * B))
    assert cov[0, 0, 0] == cov[0, 1, 1] == 0.0
