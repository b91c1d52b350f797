"""The received map and the Cliff-bot's own views, as one map to plan on (docs/team.md, "Both
agents sense"; docs/algorithm.md §8.1).

The received map's heights are within the codec's bound ``e`` of the RECON-bot's map, and that
map places each cell with the RECON-bot's horizontal error (its pose, its stereo across the
sight lines from the plateau). On level ground a horizontal error moves no height; on a slope
``s`` it moves the height by ``s`` times the error: just past a lip the RECON-bot's cells can
read decimetres off (the plateau's height carried over the edge, the lip's mixed pixels read
as a pit behind it), while a Cliff-bot standing there sees the same ground from a metre or two
with its own, honest, variance. So a received cell's variance is
``e^2 / 3 + (s sigma_h)^2`` (the codec's uniform error; ``s`` the steepest known central
difference round the cell, ``sigma_h`` ``[cliffbot_sensing] received_xy_sigma_m``), and where
the Cliff-bot's own map knows the cell too the two heights are fused by inverse variance, as
the map fuses any two measurements of a cell (§1.2): on level ground the received height
stands, past a lip the nearer views decide.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


def steepest_slope(z: F64, cell_m: float) -> F64:
    """Each cell's steepest known slope (rise over run): the largest central difference, along
    either axis, at the cell and its 8 neighbours, of the known cells (NaN beside an unknown
    cell is skipped; 0 where none is known). The neighbours count: the cell's horizontal error
    can take it to any of them."""
    gy, gx = np.gradient(np.asarray(z, np.float64), cell_m)
    g = np.fmax(np.abs(gx), np.abs(gy))
    g = np.where(np.isfinite(g), g, 0.0)
    p = np.pad(g, 1, constant_values=0.0)
    ny, nx = g.shape
    return np.max([p[1 + dy:1 + dy + ny, 1 + dx:1 + dx + nx] for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0)


def received_variance(z: F64, cell_m: float, error_bound_m: float, xy_sigma_m: float) -> F64:
    """The variance of each received height (module docstring): the codec's uniform error plus
    the slope times the RECON-bot's horizontal error, squared (inf on unknown cells)."""
    zf = np.asarray(z, np.float64)
    s = steepest_slope(zf, cell_m)
    var = error_bound_m ** 2 / 3.0 + (s * xy_sigma_m) ** 2
    return np.where(np.isfinite(zf), var, np.inf)


def merge_own(received: F64, own: F64, own_var: F64, cell_m: float, error_bound_m: float,
              xy_sigma_m: float) -> tuple[F64, NDArray[np.bool_]]:
    """The map to plan on: the received heights, the Cliff-bot's own where the received map does
    not know the cell, and both fused by inverse variance where both know it (module docstring).
    Returns the map and the cells its own views set or moved (own known, finite variance)."""
    rz = np.asarray(received, np.float64)
    oz = np.asarray(own, np.float64)
    ov = np.asarray(own_var, np.float64)
    mine = np.isfinite(oz) & np.isfinite(ov) & (ov > 0.0)
    rv = received_variance(rz, cell_m, error_bound_m, xy_sigma_m)
    out = rz.copy()
    fill = mine & ~np.isfinite(rz)
    out[fill] = oz[fill]
    both = mine & np.isfinite(rz)
    w_r, w_o = 1.0 / rv[both], 1.0 / ov[both]
    out[both] = (w_r * rz[both] + w_o * oz[both]) / (w_r + w_o)
    return out, mine
