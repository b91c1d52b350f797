"""The calibration file and on-board rectification (issue 14, item 2): the file round-trips
and is validated at start-up, the maps are built once from it, banded rectification equals
whole-image rectification, and triangulation through the rectified camera recovers the
terrain from a distorted, misaligned pair that unrectified stereo gets wrong."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from step_count import count_steps

from fsw.cli import main as fsw_main
from fsw.core.geometry import CameraConfig, camera_pose_from_rover
from fsw.core.stereo.rectify import Rectifier
from fsw.core.stereo.stereo import StereoMatcher
from fsw.drivers.calibration_file import CalibrationError, load_calibration, save_calibration
from fsw.framework.params import ConfigError
from fsw.settings import DEFAULT_CONFIG, load_settings, load_stereo_calibration
from hil_sim.camera_model import CameraModelConfig, TrueCameras
from hil_sim.render import StereoRenderer
from hil_sim.rig import load_hardware
from hil_sim.world import load_scenario

CAM = CameraConfig()


@pytest.fixture(scope="module")
def cams() -> TrueCameras:
    return TrueCameras.from_config(CAM, load_hardware().camera)


def test_shipped_config_names_a_valid_calibration_of_the_bench_cameras(cams: TrueCameras) -> None:
    cfg = load_settings()
    cal = load_stereo_calibration(cfg)
    assert cal is not None and cal.views >= 15 and cal.rms_px <= 0.3
    truth = cams.truth()
    assert abs(cal.K1[0, 0] / truth.K1[0, 0] - 1) <= 0.005
    assert abs(cal.baseline_m / truth.baseline_m - 1) <= 0.01


def test_file_round_trip_and_maps_are_fixed_point(cams: TrueCameras, tmp_path: Path) -> None:
    path = tmp_path / "cal.yaml"
    save_calibration(path, cams.truth())
    cal = load_calibration(path, 640, 480)
    for name in ("K1", "D1", "K2", "D2", "R", "T"):
        np.testing.assert_allclose(getattr(cal, name), getattr(cams.truth(), name), atol=1e-12)
    rect = Rectifier(cal, CAM.K)
    for m1, m2 in rect.maps:
        assert m1.dtype == np.int16 and m1.shape == (480, 640, 2) and m2.dtype == np.uint16
    cam = rect.camera
    assert cam.focal_px == pytest.approx(CAM.focal_px) and cam.baseline_m == pytest.approx(cal.baseline_m)


def _mutate(src: Path, dst: Path, key: str, value: str) -> Path:
    lines = src.read_text().splitlines()
    out, skip = [], False
    for line in lines:
        if skip and line.startswith((" ", "\t")):
            continue
        skip = False
        if line.startswith(f"{key}:"):
            skip = True
            if value:
                out.append(f"{key}: {value}")
            continue
        out.append(line)
    dst.write_text("\n".join(out) + "\n")
    return dst


MAT = "!!opencv-matrix\n   rows: {r}\n   cols: {c}\n   dt: d\n   data: [ {d} ]"


@pytest.mark.parametrize("key,value,match", [
    ("image_width", "320", "calibrated for 320x480 images but the camera is 640x480"),
    ("K1", "", "K1 missing"),
    ("D2", MAT.format(r=1, c=4, d="0., 0., 0., 0."), "D2 has shape"),
    ("K1", MAT.format(r=3, c=3, d=".nan, 0., 320., 0., 690., 240., 0., 0., 1."), "K1 has non-finite values"),
    ("R", MAT.format(r=3, c=3, d="2., 0., 0., 0., 1., 0., 0., 0., 1."), "R is not a rotation"),
    ("T", MAT.format(r=3, c=1, d="0., 0., 0."), "T has no baseline"),
    ("T", MAT.format(r=3, c=1, d="0.15, 0., 0."), "pair swapped"),
    ("P1", MAT.format(r=3, c=4, d="700., 0., 320., 0., 0., 700., 240., 0., 0., 0., 1., 0."), "stored P1 disagrees"),
    ("image_height", "\"tall\"", "image_height missing or not an integer"),
    ("disparity_offset_sigma_px", "-1.", "disparity_offset_sigma_px = -1.0 is not a sigma"),
    ("disparity_offset_sigma_px", ".nan", "is not a sigma"),
    # malformed matrix nodes that make OpenCV's own reader corrupt its heap (found by the fuzz test)
    ("K2", "!!opencv-matrix\n   rows: -1\n   cols: 3\n   dt: d\n   data: [ 1., 2., 3. ]", "K2 is not a matrix"),
    ("R", "!!opencv-matrix\n   rows: 3\n   dt: d\n   data: [ 1. ]", "R is not a matrix"),
    ("D1", MAT.format(r=1, c=5, d="0., 0., 0., 0."), "D1 data must hold rows \\* cols = 5 numbers"),
])
def test_inconsistent_files_are_refused_in_one_line(cams: TrueCameras, tmp_path: Path, key: str, value: str,
                                                    match: str) -> None:
    good = tmp_path / "good.yaml"
    save_calibration(good, cams.truth())
    bad = _mutate(good, tmp_path / "bad.yaml", key, value)
    with pytest.raises(CalibrationError, match=match) as exc:
        load_calibration(bad, 640, 480)
    assert "\n" not in str(exc.value)


def test_missing_and_garbage_files_are_refused(tmp_path: Path) -> None:
    with pytest.raises(CalibrationError, match="calibration file not found"):
        load_calibration(tmp_path / "none.yaml", 640, 480)
    (tmp_path / "junk.yaml").write_bytes(b"\x00\xffnot yaml at all {{{")
    with pytest.raises(CalibrationError, match="not an OpenCV FileStorage YAML"):
        load_calibration(tmp_path / "junk.yaml", 640, 480)
    (tmp_path / "broken.yaml").write_text("%YAML:1.0\n---\nK1: !!opencv-matrix\n  rows: [\n")
    with pytest.raises(CalibrationError, match="broken.yaml: "):
        load_calibration(tmp_path / "broken.yaml", 640, 480)


def test_bad_calibration_file_is_a_start_up_error_exit_2(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    text = DEFAULT_CONFIG.read_text().replace(
        'calibration_file = "config/stereo_calibration.yaml"', f'calibration_file = "{tmp_path / "none.yaml"}"')
    cfg_path = tmp_path / "fsw.toml"
    cfg_path.write_text(text)
    with pytest.raises(ConfigError, match="camera.calibration_file: .*calibration file not found"):
        load_settings(cfg_path)
    assert fsw_main(["run", "--config", str(cfg_path), "--duration", "0.1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "camera.calibration_file" in err and "\n" not in err


def test_banded_rectification_equals_whole_image(cams: TrueCameras) -> None:
    rect = Rectifier(cams.truth(), CAM.K)
    rng = np.random.default_rng(0)
    left, right = (rng.integers(0, 256, (480, 640), dtype=np.uint8) for _ in range(2))
    whole = rect.rectify(left, right)
    slices, banded = count_steps(rect.rectify_steps(left, right, 120))
    assert slices == 4
    for a, b in zip(whole, banded, strict=True):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="raw left image must be uint8 of shape"):
        rect.rectify(left[:-1], right)


def test_rectified_points_follow_the_epipolar_rows(cams: TrueCameras) -> None:
    """A 3-D point seen through the true (distorted, misaligned) cameras lands on the same
    row of both rectified images, and its disparity gives its depth with the rectified f, B."""
    rect = Rectifier(cams.truth(), CAM.K)
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(-1, 1, 200), rng.uniform(-0.7, 0.7, 200), rng.uniform(1.5, 5.0, 200)])
    pl = cams.project(0, pts)
    pr = cams.project(1, (pts - [cams.baseline_m, 0, 0]) @ cams.right_rotation)
    R1, R2, _, _, _ = cams.truth().rectification()
    P1 = np.hstack([CAM.K, np.zeros((3, 1))])
    P2 = np.hstack([CAM.K, CAM.K @ np.array([[-cams.baseline_m], [0], [0]])])
    ul = cv2.undistortPoints(pl.reshape(-1, 1, 2), cams.K[0], cams.dist[0], R=R1, P=P1).reshape(-1, 2)
    ur = cv2.undistortPoints(pr.reshape(-1, 1, 2), cams.K[1], cams.dist[1], R=R2, P=P2).reshape(-1, 2)
    assert np.abs(ul[:, 1] - ur[:, 1]).max() < 1e-3
    z_rect = rect.camera.focal_px * rect.camera.baseline_m / (ul[:, 0] - ur[:, 0])
    x_rect = np.column_stack([(ul[:, 0] - rect.camera.cx_px) * z_rect / rect.camera.focal_px,
                              (ul[:, 1] - rect.camera.cy_px) * z_rect / rect.camera.focal_px, z_rect])
    np.testing.assert_allclose(x_rect @ rect.camera.R_rect, pts, atol=1e-5)


def test_stereo_on_a_distorted_pair_needs_rectification(cams: TrueCameras) -> None:
    """Lab terrain through the real cameras: rectified, the points lie on the true terrain
    about as well as through the ideal cameras; fed raw to the matcher, far worse."""
    cfg = load_settings()
    world = load_scenario("lab", 0)
    pose = camera_pose_from_rover(world.rover_start, (np.radians(-90), np.radians(-45), 0.5), cfg.mast,
                                  world.plateau_z)
    left, right = StereoRenderer(world, cfg.camera, 1.0, 0, cameras=cams).render(pose)
    ideal = StereoRenderer(world, cfg.camera, 1.0, 0).render(pose)
    rect = Rectifier(cams.truth(), cfg.camera.K)
    errs = {}
    for name, matcher, pair in (("rectified", StereoMatcher(cfg.stereo, cfg.camera, rect.camera),
                                 rect.rectify(left, right)),
                                ("ideal", StereoMatcher(cfg.stereo, cfg.camera), ideal),
                                ("raw", StereoMatcher(dataclasses.replace(cfg.stereo, drift_correction=False),
                                                      cfg.camera), (left, right)),
                                ("raw, drift corrected", StereoMatcher(cfg.stereo, cfg.camera), (left, right))):
        pts = matcher.points(*pair, stride_px=4)
        xyz = pose.camera_to_world(pts.xyz_c)
        errs[name] = (float(np.median(np.abs(xyz[:, 2] - world.height_at(xyz[:, 0], xyz[:, 1])))), len(pts))
    (e_rect, n_rect), (e_ideal, n_ideal), (e_raw, n_raw) = errs["rectified"], errs["ideal"], errs["raw"]
    assert n_rect >= 0.9 * n_ideal and e_rect <= 1.4 * e_ideal
    assert n_raw < 0.3 * n_rect and e_raw > 10 * e_rect
    # the per-pair drift correction (a vertical shift and roll) matches more of the raw pair, but
    # cannot undo the lens distortion: its points stay far off the terrain
    print(errs)
    assert errs["raw, drift corrected"][0] > 5 * e_rect


def test_ideal_model_is_the_nominal_pinhole_pair() -> None:
    ideal = TrueCameras.from_config(CAM, dataclasses.replace(CameraModelConfig(), model="ideal", k1=-0.2))
    assert ideal.ideal and ideal.baseline_m == CAM.baseline_m
    np.testing.assert_array_equal(ideal.K[1], CAM.K)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_fuzzed_calibration_files_load_or_fail_cleanly(cams: TrueCameras, tmp_path: Path, data) -> None:  # type: ignore[no-untyped-def]
    """Truncated, bit-flipped or digit-edited files: a clean CalibrationError or a calibration
    that passed every check, never another exception."""
    good = tmp_path / "good.yaml"
    if not good.exists():
        save_calibration(good, cams.truth())
    raw = bytearray(good.read_bytes())
    for _ in range(data.draw(st.integers(1, 4))):
        kind = data.draw(st.sampled_from(["number", "number", "number", "flip", "digit", "cut"]))
        if kind == "number":  # keeps the file parseable: reaches the checks behind the parser
            spans = [m.span() for m in re.finditer(rb"-?\d+\.?\d*(?:e[-+]?\d+)?", bytes(raw))]
            if not spans:
                continue
            a, b = data.draw(st.sampled_from(spans))
            value = data.draw(st.one_of(st.sampled_from([".nan", ".inf", "-.inf", "0.", "-1.", "1e300"]),
                                        st.floats(-2000, 2000).map(repr)))
            raw[a:b] = value.encode()
            continue
        i = data.draw(st.integers(0, len(raw) - 1))
        if kind == "flip":
            raw[i] ^= 1 << data.draw(st.integers(0, 7))
        elif kind == "digit":
            raw[i:i + 1] = data.draw(st.sampled_from([b"9", b"-", b".", b"e", b"nan", b" ", b"]"]))
        else:
            del raw[i:]
            if not raw:
                break
    bad = tmp_path / "fuzz.yaml"
    bad.write_bytes(bytes(raw))
    try:
        cal = load_calibration(bad, 640, 480)
    except CalibrationError as err:
        assert "\n" not in str(err) and str(bad) in str(err)
        return
    for name in ("K1", "D1", "K2", "D2", "R", "T"):
        assert np.isfinite(getattr(cal, name)).all()
    # the loader's rotation check (np.allclose: atol 1e-6 plus rtol 1e-5), not a stricter one
    np.testing.assert_allclose(cal.R @ cal.R.T, np.eye(3), rtol=1e-5, atol=1e-6)
    Rectifier(cal, CAM.K)  # usable: the maps build


def test_a_matrix_type_that_is_not_utf8_text_is_refused_cleanly(cams: TrueCameras, tmp_path: Path) -> None:
    """A flipped high bit in a matrix's ``dt`` (a byte OpenCV passes on undecoded) is a
    CalibrationError naming the file, not a UnicodeDecodeError."""
    good = tmp_path / "good.yaml"
    save_calibration(good, cams.truth())
    raw = good.read_bytes()
    at = raw.index(b"K2:")
    dt = raw.index(b"dt: d", at) + len(b"dt: ")
    bad = tmp_path / "bad.yaml"
    bad.write_bytes(raw[:dt] + b"\xa0" + raw[dt + 1:])
    with pytest.raises(CalibrationError, match="K2 is not a matrix of reals") as err:
        load_calibration(bad, 640, 480)
    assert str(bad) in str(err.value) and "\n" not in str(err.value)
