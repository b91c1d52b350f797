"""Issue 29, item 5: the Cliff-bot's map picture has axes in metres and the orientation of
``map.png`` (row 0 = lowest y drawn at the bottom)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from hil_sim.cliffbot_receiver import write_figure13


def test_the_cliffbot_picture_is_drawn_with_low_y_at_the_bottom(tmp_path: Path) -> None:
    z = np.full((60, 60), 0.5)
    z[:30] = np.nan  # rows 0..29 = the low-y half unknown (red)
    path = tmp_path / "fig.png"
    write_figure13(z, z, path, "t", cell_m=0.05)
    img = cv2.imread(str(path))
    h, w = img.shape[:2]
    col = int(0.3 * w)  # inside the left panel
    top, bottom = img[int(0.35 * h), col].astype(int), img[int(0.75 * h), col].astype(int)
    red = lambda bgr: bgr[2] > 150 and bgr[1] < 100 and bgr[0] < 100  # noqa: E731
    assert red(bottom) and not red(top)
