"""A real DEM for the ``file:`` scenario: matplotlib's Jacksboro fault sample, at rover scale,
with a cliff drop added (issue 13 item 4; docs/world.md, "Bring your own DEM").

matplotlib ships ``jacksboro_fault_dem.npz`` (USGS 3 arc-second DEM of the Jacksboro fault,
Tennessee: 344 x 403 cells of about 90 m, heights 236-1076 m, int16 metres). Scaled to rover
size by geometric similarity (every length, heights included, times ``cell_m / 90 m``), its
slopes stay the real terrain's. A cliff face of ``face_slope_deg`` drops ``drop_m`` below the
line ``y = edge_y_m`` (world metres, the DEM's corner at ``(x_min_m, y_min_m)``), so the
mission has an edge to follow. The result is a ``.npy`` of float32 metres, ``[iy, ix]`` with row
0 at the lowest ``y``, as the ``file:`` scenario reads it::

    python -m hil_sim.world.sample_dem out/jacksboro.npy
    safer-hil run --scenario file:out/jacksboro.npy?cell_m=0.03 --method 5 --steps 10
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

SOURCE_CELL_M = 90.0  # 3 arc-seconds of latitude, about 92 m; the npz's longitude step is 75 m


def jacksboro_dem(cell_m: float = 0.03, drop_m: float = 1.0, edge_y_m: float = -1.0,
                  face_slope_deg: float = 75.0, y_min_m: float = -6.0) -> NDArray[np.float32]:
    """The Jacksboro sample DEM at ``cell_m`` metres per cell with a cliff drop (metres)."""
    from matplotlib import cbook

    with cbook.get_sample_data("jacksboro_fault_dem.npz") as data:
        z = np.asarray(data["elevation"], np.float64)[::-1]  # the npz runs north to south
    z = (z - z.min()) * (cell_m / SOURCE_CELL_M)
    ys = y_min_m + (np.arange(z.shape[0]) + 0.5) * cell_m
    past = np.maximum(edge_y_m - ys, 0.0)[:, None]  # horizontal distance past the edge line
    face = np.minimum(past * math.tan(math.radians(face_slope_deg)), drop_m)
    return np.asarray(z - face, np.float32)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m hil_sim.world.sample_dem", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("out", type=Path, help="the .npy to write")
    p.add_argument("--cell", type=float, default=0.03, help="metres per DEM cell (default 0.03)")
    p.add_argument("--drop", type=float, default=1.0, help="cliff drop, m (default 1.0)")
    p.add_argument("--edge-y", type=float, default=-1.0, help="edge line y, m (default -1.0)")
    a = p.parse_args(argv)
    if not (0.001 <= a.cell <= 1.0 and 0.0 <= a.drop <= 20.0 and math.isfinite(a.edge_y)):
        print("sample_dem: need 0.001 <= --cell <= 1, 0 <= --drop <= 20, a finite --edge-y",
              file=sys.stderr)
        return 2
    a.out.parent.mkdir(parents=True, exist_ok=True)
    np.save(a.out, jacksboro_dem(a.cell, a.drop, a.edge_y))
    print(f"{a.out}: Jacksboro DEM at {a.cell} m/cell, drop {a.drop} m below y = {a.edge_y} m")
    return 0


if __name__ == "__main__":
    sys.exit(main())
