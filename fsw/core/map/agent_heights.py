"""Which height the Cliff-bot plans on where two agents measured a cell (docs/algorithm.md §8,
"Two agents' heights of a cell"; docs/team.md, "Both agents sense").

The Cliff-bot holds two maps of the same cells: the one it received (the RECON-bot's, within
the codec's bound; its variance does not cross the link) and its own (its views, each cell with
its variance, §1.2). Where only one knows a cell, that one's height stands. Where both do:

* the received height's variance is taken as ``received_sigma_m**2`` (the RECON-bot's map error
  on the ground the Cliff-bot works on) plus the codec's ``bound**2 / 3`` (a height within
  ``±bound`` of the RECON-bot's, uniform);
* when the two agree within ``gate_sigma`` standard deviations of their difference, the cell
  takes their inverse-variance mean (§1.3, the same rule a view's height meets in the map);
* when they disagree, one of them is wrong by more than its noise (a lip's mixed pixels put
  the face's heights on the ground behind the lip, seen from the top; a view across a step
  smears it) and the mean would carry that error on: the height with the smaller variance
  stands alone.

The rule is symmetric in the agents and needs nothing but each map and its variance; with no
own height anywhere the result is the received map unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Heights:
    """The heights planned on (NaN unknown) and, per cell, how they came."""

    z: F64
    filled: int  # cells only its own views know
    fused: int  # cells both know, agreeing: their inverse-variance mean
    own_won: int  # cells both know, disagreeing: its own (the smaller variance)
    received_won: int  # cells both know, disagreeing: the received (the smaller variance)


def plan_heights(received: F64, bound_m: float, own: F64, own_var: F64, received_sigma_m: float,
                 gate_sigma: float) -> Heights:
    """The heights the Cliff-bot plans on from the ``received`` map (within ``bound_m`` of the
    RECON-bot's) and its ``own`` map with its variance ``own_var`` (module docstring)."""
    zr = np.asarray(received, np.float64)
    zo = np.asarray(own, np.float64)
    vo = np.asarray(own_var, np.float64)
    z = zr.copy()
    ok_own = np.isfinite(zo) & np.isfinite(vo) & (vo >= 0.0)
    fill = ~np.isfinite(zr) & ok_own
    z[fill] = zo[fill]
    both = np.isfinite(zr) & ok_own
    vr = float(received_sigma_m) ** 2 + float(bound_m) ** 2 / 3.0
    d = np.where(both, zo - zr, 0.0)
    total = np.where(both, vo + vr, 1.0)
    agree = both & (d * d <= (gate_sigma * gate_sigma) * total)
    w_own = np.where(agree, vr / np.maximum(total, 1e-300), 0.0)
    z[agree] = zr[agree] + w_own[agree] * d[agree]
    own_won = both & ~agree & (vo < vr)
    z[own_won] = zo[own_won]
    return Heights(z, int(fill.sum()), int(agree.sum()), int(own_won.sum()),
                   int((both & ~agree & ~own_won).sum()))
