"""The map the Cliff-bot plans on: the RECON-bot's received map and its own views' map, fused
by variance (docs/algorithm.md §8, "Fusion from several agents"; the update is §1.1's).

Every agent's measurements enter the one map with their variances. The received map comes
over the link without the RECON-bot's variances: what the Cliff-bot knows of a received cell's
error is the codec's bound ``e`` (every known cell within ``e`` of the RECON-bot's map, taken
uniform: a variance of ``e^2 / 3``), a floor of its true error, which adds the RECON-bot's own.
Its own map holds each cell's whole variance (the stereo's and its pose's, §1.2). So, per cell
both know, the received height is the prior and its own the measurement of §1.1's update: within
the Mahalanobis gate (``gate_sigma`` of both variances together) the inverse-variance mean;
beyond it the two disagree by more than both variances allow, and since only the received
cell's variance can be short of its error (its floor), its own height is kept. A cell one of
them knows takes that one's height.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]
B = NDArray[np.bool_]


@dataclass(frozen=True)
class MergedMap:
    """The fused heights (NaN unknown) and which cells came from its own map alone (``own_only``:
    unknown to the received map), were fused (``fused``) or were its own because the two
    disagreed beyond the gate (``disputed``)."""

    z: F64
    own_only: B
    fused: B
    disputed: B


def merge_received(received: F64, error_bound_m: float, own: F64, own_var: F64, gate_sigma: float) -> MergedMap:
    """Fuse the received map (codec bound ``error_bound_m``) with its own map (heights ``own``,
    variances ``own_var``; NaN or inf where unknown) as the module docstring says."""
    zr = np.asarray(received, np.float64)
    zo = np.asarray(own, np.float64)
    vo = np.asarray(own_var, np.float64)
    e = float(error_bound_m) if np.isfinite(error_bound_m) and error_bound_m > 0 else 0.0
    vr = e * e / 3.0
    has_r = np.isfinite(zr)
    has_o = np.isfinite(zo) & np.isfinite(vo) & (vo >= 0)
    both = has_r & has_o
    out = np.where(has_r, zr, np.where(has_o, zo, np.nan))
    with np.errstate(invalid="ignore", divide="ignore"):
        tot = vr + vo
        d = np.abs(zo - zr) / np.sqrt(tot)
        # a received map without a bound (e = 0) is taken as exact: its own cells agree with it or lose
        inside = both & ((tot > 0) & (d <= gate_sigma) | (tot == 0))
        disputed = both & ~inside & (vr > 0)
        mean = np.where(tot > 0, (vo * zr + vr * zo) / tot, zr)
    out[inside] = mean[inside]
    out[disputed] = zo[disputed]
    return MergedMap(out, has_o & ~has_r, inside & (vr > 0), disputed)
