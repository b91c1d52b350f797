"""Issue 29, item 5: the Cliff-bot's map picture (the paper's Figure 13) has axes in metres, the
orientation of ``map.png`` (row 0 = lowest y drawn at the bottom), and unknown cells and hazard
outlines in distinct colours named by a legend."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from hil_sim.cliffbot_receiver import HAZARD_COLOUR, UNKNOWN_COLOUR, write_figure13


def _bgr(hex_colour: str) -> np.ndarray:
    return np.array([int(hex_colour[i:i + 2], 16) for i in (5, 3, 1)])


def _near(img: np.ndarray, hex_colour: str, tol: int = 40) -> np.ndarray:
    return np.abs(img.astype(int) - _bgr(hex_colour)).max(axis=2) <= tol


def test_the_cliffbot_picture_is_drawn_with_low_y_at_the_bottom(tmp_path: Path) -> None:
    z = np.full((60, 60), 0.5)
    z[:30] = np.nan  # rows 0..29 = the low-y half unknown
    path = tmp_path / "fig.png"
    write_figure13(z, z, path, "t", cell_m=0.05)
    img = cv2.imread(str(path))
    h, w = img.shape[:2]
    col = int(0.3 * w)  # inside the left panel
    top, bottom = img[int(0.35 * h), col:col + 1], img[int(0.75 * h), col:col + 1]
    assert _near(bottom[None], UNKNOWN_COLOUR).all() and not _near(top[None], UNKNOWN_COLOUR).any()


def test_unknown_cells_and_hazards_have_distinct_colours(tmp_path: Path) -> None:
    """Hazard outlines and unknown cells never share a colour; each appears only when the map has it
    (the legend's patch and line included)."""
    assert np.abs(_bgr(UNKNOWN_COLOUR) - _bgr(HAZARD_COLOUR)).max() > 120
    rng = np.random.default_rng(1)
    z = rng.normal(0.0, 0.01, (60, 60))
    hazard = np.zeros_like(z, bool)
    hazard[40:50, 40:50] = True
    counts = {}
    for name, zz, outlines in (("plain", z, None), ("holes", np.where(np.arange(60)[:, None] < 10, np.nan, z), None),
                               ("hazards", z, (hazard, hazard))):
        write_figure13(zz, zz, tmp_path / f"{name}.png", "t", outlines=outlines, cell_m=0.05)
        img = cv2.imread(str(tmp_path / f"{name}.png"))
        counts[name] = (int(_near(img, UNKNOWN_COLOUR).sum()), int(_near(img, HAZARD_COLOUR).sum()))
    assert counts["plain"] == (0, 0)
    assert counts["holes"][0] > 1000 and counts["holes"][1] == 0
    assert counts["hazards"][0] == 0 and counts["hazards"][1] > 50
