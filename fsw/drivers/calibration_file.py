"""The stereo calibration file (``fsw.core.stereo.stereo_calibration.StereoCalibration`` on disk).

A calibration is what ``safer-fsw calibrate`` estimates from views of a target and what the
flight software rectifies with (``fsw.core.stereo.rectify``): for each camera the matrix ``K`` and
the Brown–Conrady distortion ``D = (k1, k2, p1, p2, k3)`` of OpenCV's model, and the pose of
the right camera in the left camera's frame, ``x_right = R x_left + T`` (metres). The left
camera is the reference (``fsw.core.geometry``), so ``T`` is close to ``(-baseline, 0, 0)``.

The file is an OpenCV ``FileStorage`` YAML (``%YAML:1.0``), readable by any OpenCV tool:

    image_width, image_height      int, pixels
    K1, D1, K2, D2, R, T           matrices (3x3, 1x5, 3x3, 1x5, 3x3, 3x1)
    rms_px                         stereo reprojection RMS of the fit, px
    views                          views used
    disparity_offset_sigma_px      the calibration's disparity offset sigma (optional, 0)
    R1, R2, P1, P2, Q              the rectification (cv2.stereoRectify) for other tools

Loading validates everything and raises :class:`CalibrationError` with one line naming the
file and the problem: missing file or node, wrong shape, non-finite values, an image size
other than the camera's, a matrix that is not a camera matrix, ``R`` not a rotation, no
baseline, or stored rectification matrices that disagree with the calibration.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from fsw.core.stereo.stereo_calibration import F64, StereoCalibration

_SHAPES = {"K1": (3, 3), "D1": (1, 5), "K2": (3, 3), "D2": (1, 5), "R": (3, 3), "T": (3, 1)}
_RECT_SHAPES = {"R1": (3, 3), "R2": (3, 3), "P1": (3, 4), "P2": (3, 4), "Q": (4, 4)}


class CalibrationError(ValueError):
    """A calibration file that cannot be used, reported as ``file: reason`` on one line."""


def save_calibration(path: str | Path, cal: StereoCalibration) -> None:
    """Write ``cal`` (and its rectification) as an OpenCV FileStorage YAML."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_FORMAT_YAML)
    if not fs.isOpened():
        raise CalibrationError(f"{path}: cannot be written")
    try:
        fs.write("image_width", int(cal.width_px))
        fs.write("image_height", int(cal.height_px))
        for name in _SHAPES:
            fs.write(name, np.asarray(getattr(cal, name), np.float64).reshape(_SHAPES[name]))
        fs.write("rms_px", float(cal.rms_px))
        fs.write("views", int(cal.views))
        fs.write("disparity_offset_sigma_px", float(cal.disparity_offset_sigma_px))
        for name, mat in zip(_RECT_SHAPES, cal.rectification(), strict=True):
            fs.write(name, mat)
    finally:
        fs.release()


def load_calibration(path: str | Path, width_px: int, height_px: int) -> StereoCalibration:
    """Read and validate a calibration file for a camera of ``width_px`` x ``height_px``."""
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"{path}: calibration file not found")
    try:
        with path.open("rb") as fh:
            head = fh.read(9)
    except OSError as exc:
        raise CalibrationError(f"{path}: unreadable ({exc.strerror or exc})") from None
    if not head.startswith(b"%YAML"):
        raise CalibrationError(f"{path}: not an OpenCV FileStorage YAML (no %YAML header)")
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # the parser's errors surface as either
        raise CalibrationError(f"{path}: not an OpenCV FileStorage file ({_first_line(exc)})") from None
    if not fs.isOpened():
        raise CalibrationError(f"{path}: not an OpenCV FileStorage file")
    try:
        size = [_read_int(fs, path, k) for k in ("image_width", "image_height")]
        mats = {k: _required(_read_mat(fs, path, k, shape)) for k, shape in _SHAPES.items()}
        stored = {k: _read_mat(fs, path, k, shape, required=False) for k, shape in _RECT_SHAPES.items()}
        rms_node, views_node = fs.getNode("rms_px"), fs.getNode("views")  # informative only
        rms = rms_node.real() if rms_node.isReal() or rms_node.isInt() else float("nan")
        views = int(views_node.real()) if views_node.isInt() else 0
        off_node = fs.getNode("disparity_offset_sigma_px")  # optional: files before it read as 0
        off = off_node.real() if off_node.isReal() or off_node.isInt() else 0.0
    except (cv2.error, SystemError) as exc:
        raise CalibrationError(f"{path}: unreadable node ({_first_line(exc)})") from None
    finally:
        fs.release()
    if (size[0], size[1]) != (width_px, height_px):
        raise CalibrationError(
            f"{path}: calibrated for {size[0]}x{size[1]} images but the camera is {width_px}x{height_px}")
    for k in ("K1", "K2"):
        K = mats[k]
        if not (K[0, 0] > 0 and K[1, 1] > 0 and K[2, 2] == 1.0 and K[1, 0] == K[2, 0] == K[2, 1] == 0.0):
            raise CalibrationError(f"{path}: {k} is not a camera matrix (positive focal lengths, last row 0 0 1)")
        if not (0 <= K[0, 2] < width_px and 0 <= K[1, 2] < height_px):
            raise CalibrationError(f"{path}: {k} principal point lies outside the image")
    R = mats["R"]
    # A rotation's entries lie in [-1, 1]: test that first (a huge entry would overflow R R^T).
    if not (np.abs(R).max() <= 1.0 + 1e-6 and np.allclose(R @ R.T, np.eye(3), atol=1e-6)
            and np.linalg.det(R) > 0):
        raise CalibrationError(f"{path}: R is not a rotation matrix")
    if not np.linalg.norm(mats["T"]) > 1e-6:
        raise CalibrationError(f"{path}: T has no baseline")
    right_centre = -R.T @ mats["T"]  # in the left camera frame: it must lie along +x
    if not right_centre[0, 0] > 0.5 * np.linalg.norm(mats["T"]):
        raise CalibrationError(f"{path}: the right camera is not to the right of the left one (pair swapped?)")
    if not (math.isfinite(off) and 0.0 <= off <= 5.0):
        raise CalibrationError(f"{path}: disparity_offset_sigma_px = {off} is not a sigma in 0..5 px")
    cal = StereoCalibration(width_px, height_px, **mats, rms_px=float(rms), views=views,
                            disparity_offset_sigma_px=float(off))
    present = {k: v for k, v in stored.items() if v is not None}
    if present:
        for k, mine in zip(_RECT_SHAPES, cal.rectification(), strict=True):
            if k in present and not np.allclose(present[k], mine, rtol=1e-6, atol=1e-6):
                raise CalibrationError(f"{path}: stored {k} disagrees with the calibration (edited by hand?)")
    return cal


def _required(mat: F64 | None) -> F64:
    assert mat is not None  # _read_mat raised for a missing required node
    return mat


def _first_line(exc: Exception) -> str:
    text = str(exc).strip().splitlines()
    return text[-1].strip() if text else type(exc).__name__


def _read_int(fs: cv2.FileStorage, path: Path, key: str) -> int:
    node = fs.getNode(key)
    if node.empty() or not node.isInt():
        raise CalibrationError(f"{path}: {key} missing or not an integer")
    value = int(node.real())
    if not 1 <= value <= 65535:
        raise CalibrationError(f"{path}: {key} = {value} is not an image size")
    return value


def _text(node: cv2.FileNode) -> str | None:
    """A string node's text, or None where its bytes are not UTF-8 (OpenCV hands them on as they
    are in the file, and decoding them would raise)."""
    try:
        return node.string()
    except UnicodeDecodeError:
        return None


def _check_matrix_node(node: cv2.FileNode, path: Path, key: str) -> None:
    """A well-formed ``!!opencv-matrix``: small integer ``rows`` and ``cols``, a real ``dt``
    and exactly ``rows * cols`` numbers in ``data``."""
    if not node.isMap():
        raise CalibrationError(f"{path}: {key} is not a matrix")
    rows, cols, dt, data = (node.getNode(k) for k in ("rows", "cols", "dt", "data"))
    if not (rows.isInt() and cols.isInt() and 1 <= rows.real() <= 16 and 1 <= cols.real() <= 16):
        raise CalibrationError(f"{path}: {key} is not a matrix (rows and cols must be small integers)")
    if not (dt.isString() and _text(dt) in ("d", "f")):
        raise CalibrationError(f"{path}: {key} is not a matrix of reals (dt must be d or f)")
    n = int(rows.real()) * int(cols.real())
    if not (data.isSeq() and data.size() == n):
        raise CalibrationError(f"{path}: {key} data must hold rows * cols = {n} numbers")
    for i in range(n):
        item = data.at(i)
        if not (item.isReal() or item.isInt()):
            raise CalibrationError(f"{path}: {key} data item {i} is not a number")


def _read_mat(fs: cv2.FileStorage, path: Path, key: str, shape: tuple[int, int],
              required: bool = True) -> F64 | None:
    node = fs.getNode(key)
    if node.empty():
        if required:
            raise CalibrationError(f"{path}: {key} missing")
        return None
    _check_matrix_node(node, path, key)  # OpenCV's own reader corrupts its heap on some malformed nodes
    raw = node.mat()
    if raw is None:
        raise CalibrationError(f"{path}: {key} is not a matrix")
    mat: F64 = np.array(raw, dtype=np.float64)
    if mat.size == shape[0] * shape[1] and 1 in shape:
        mat = mat.reshape(shape)  # a distortion row or column vector, either way
    if mat.shape != shape:
        raise CalibrationError(f"{path}: {key} has shape {mat.shape}, expected {shape}")
    if not np.isfinite(mat).all():
        raise CalibrationError(f"{path}: {key} has non-finite values")
    return mat
