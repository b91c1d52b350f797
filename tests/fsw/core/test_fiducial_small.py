"""Far, small markers (fsw/core/localization/fiducials.py): an 18 cm marker is 12-15 px on a side
at 8-10 m; the detector as configured loses most of them, the enlarged second pass
(``[localization] fiducial_upsample``) finds them with their corners where they are."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from fsw.core.localization.fiducials import CliffbotLocalizer, _side_px
from fsw.settings import load_settings

SIDE_PX = 13  # 6 cells of about 2.2 px
PLACES = {1: (200, 220), 4: (260, 214)}  # marker id: top-left pixel of its black square


def _image() -> tuple[np.ndarray, dict[int, np.ndarray]]:
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    img = np.full((480, 640), 190.0)
    truth = {}
    for mid, (x0, y0) in PLACES.items():
        big = cv2.aruco.generateImageMarker(dictionary, mid, 240, borderBits=1).astype(np.float64)
        small = cv2.resize(big * (170 / 255) + 20, (SIDE_PX, SIDE_PX), interpolation=cv2.INTER_AREA)
        img[y0:y0 + SIDE_PX, x0:x0 + SIDE_PX] = small
        e = -0.5  # the square's outer edge, in pixel-centre coordinates
        truth[mid] = np.array([[x0 + e, y0 + e], [x0 + e + SIDE_PX, y0 + e], [x0 + e + SIDE_PX, y0 + e + SIDE_PX],
                               [x0 + e, y0 + e + SIDE_PX]])
    img = cv2.GaussianBlur(img, (0, 0), 0.7) + np.random.default_rng(3).normal(0.0, 2.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8), truth


def test_small_markers_are_found_by_the_enlarged_pass_with_their_corners() -> None:
    cfg = load_settings()
    loc = CliffbotLocalizer(cfg.localization, cfg.cliffbot, cfg.camera.K, cfg.camera.baseline_m)
    img, truth = _image()
    native = {i for i in loc.detect(img) if i in loc.corners}
    assert len(native) < 2  # as configured, these are (mostly) lost
    seen, scale = loc.detect_known(loc.corners, img)
    assert scale == cfg.localization.fiducial_upsample > 1 and set(seen) == set(PLACES)
    for mid, c in seen.items():
        assert np.abs(c - truth[mid]).max() < 0.7, (mid, c, truth[mid])
        assert abs(_side_px(c) - SIDE_PX) < 0.7
    off = CliffbotLocalizer(dataclasses.replace(cfg.localization, fiducial_upsample=1), cfg.cliffbot,
                            cfg.camera.K, cfg.camera.baseline_m)
    got, at = off.detect_known(off.corners, img)  # off: the image as it is only
    assert at == 1 and set(got) == native
