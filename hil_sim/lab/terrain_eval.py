"""Map quality on tilted ground against the world truth (issue 13: attitude and registration).

Nothing here is flight code; it reads the flight map and what each view contributed
(``MapUpdate.view_cells`` and ``camera_xyz`` of ``fsw.tasks.perception``) and
compares them with the truth:

* ``rms_m``: RMS of map minus truth over mapped cells;
* ``tilt_err_deg``: tilt of the plane fitted (least squares) to map minus truth: the map's
  residual attitude error (docs/algorithm.md §5.1);
* ``seam_m``: station seams: views are grouped into stations (camera centres within
  ``station_tol_m`` horizontally); for every pair of stations that both measured at least
  ``min_overlap`` cells, the mean height difference over those cells; reported as the
  overlap-weighted mean of its magnitude (and the worst pair, ``seam_max_m``);
* ``within_2sigma``: fraction of mapped cells with ``|error| <= 2 sigma`` (§1.2 calibrated).

**Datum.** The flight map's height origin is the rover body at the start (``fsw.core.localization.attitude``:
the body height over the start is 0; the camera chain puts the body's wheel-contact plane
there). The worlds zero their heights at the single ground cell under the rover's centre
(``zero_at_start``), and the bench's true body rests on its four wheel contacts
(``hil_sim.rover_truth``: their mean height). On level ground the two agree; on rocky or
curved ground they differ by the relief between the centre and the wheels (1.8 cm on
``terrain?slope_deg=8`` seed 3), a constant the flight software has no means to observe and
the mission does not use. ``datum_m`` (the true body height at the start in the world's
heights, from the bench truth, never fitted to the map) expresses the truth in the flight's
datum: every figure compares the map with ``truth - datum_m``. The ground-datum figures
(``rms_ground_datum_m``, ``within_2sigma_ground_datum``) are kept beside them.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


def fit_plane(grid: Any, err: F64, mask: NDArray[np.bool_]) -> tuple[F64, F64] | None:
    """Least-squares plane ``a x + b y + c`` through ``err`` over ``mask`` (finite values): its
    coefficients and the residuals around it; None with fewer than 3 cells."""
    X, Y = grid.centers()
    sel = mask & np.isfinite(err)
    if sel.sum() < 3:
        return None
    A = np.column_stack([X[sel], Y[sel], np.ones(int(sel.sum()))])
    coef, *_ = np.linalg.lstsq(A, err[sel], rcond=None)
    return coef, err[sel] - A @ coef


def plane_tilt_deg(grid: Any, err: F64, mask: NDArray[np.bool_]) -> float:
    """Tilt (deg) of the least-squares plane through ``err`` over ``mask``."""
    fit = fit_plane(grid, err, mask)
    if fit is None:
        return math.nan
    coef = fit[0]
    return math.degrees(math.atan(math.hypot(coef[0], coef[1])))


def stations(cameras: list[tuple[float, float, float]], tol_m: float = 0.05) -> list[int]:
    """Station index of each view (camera centres within ``tol_m`` horizontally share one)."""
    centres: list[tuple[float, float]] = []
    out = []
    for x, y, _ in cameras:
        for k, (cx, cy) in enumerate(centres):
            if math.hypot(x - cx, y - cy) <= tol_m:
                out.append(k)
                break
        else:
            centres.append((x, y))
            out.append(len(centres) - 1)
    return out


def seams(views: list[tuple[tuple[float, float, float], NDArray[np.int32], NDArray[np.float32]]],
          n_cells: int, min_overlap: int = 50, tol_m: float = 0.05) -> dict[str, Any]:
    """Station seams from the per-view cell means ``(camera_xyz, cell_index, z)``."""
    st = stations([v[0] for v in views], tol_m)
    n_st = max(st) + 1 if st else 0
    zsum, cnt = np.zeros((n_st, n_cells)), np.zeros((n_st, n_cells))
    for k, (_, idx, z) in zip(st, views, strict=True):
        zsum[k, idx] += z
        cnt[k, idx] += 1
    pairs = []
    for a in range(n_st):
        for b in range(a + 1, n_st):
            both = (cnt[a] > 0) & (cnt[b] > 0)
            if both.sum() >= min_overlap:
                d = zsum[a, both] / cnt[a, both] - zsum[b, both] / cnt[b, both]
                pairs.append((float(np.mean(d)), int(both.sum())))
    if not pairs:
        return {"stations": n_st, "pairs": 0, "seam_m": None, "seam_max_m": None}
    w = np.array([p[1] for p in pairs], float)
    m = np.abs([p[0] for p in pairs])
    return {"stations": n_st, "pairs": len(pairs), "seam_m": float(np.sum(w * m) / w.sum()),
            "seam_max_m": float(m.max())}


def map_quality(emap: Any, truth: F64, views: list[Any], datum_m: float = 0.0) -> dict[str, Any]:
    """The figures above for one map (``ElevationMap``) and its views; ``truth`` in the world's
    heights, ``datum_m`` the true body height at the start in them (module docstring)."""
    if not math.isfinite(datum_m):
        raise ValueError(f"datum_m must be finite, got {datum_m}")
    mapped = emap.mapped & np.isfinite(truth)
    err = np.where(mapped, emap.z - (truth - datum_m), np.nan)
    if not mapped.any():
        return {"cells": 0, "rms_m": None, "tilt_err_deg": None, "within_2sigma": None,
                "datum_m": datum_m, "rms_ground_datum_m": None, "within_2sigma_ground_datum": None,
                **seams(views, emap.grid.nx * emap.grid.ny)}
    sig = np.sqrt(emap.var[mapped])
    err_g = err[mapped] - datum_m  # against the ground under the rover's centre (before)
    return {
        "cells": int(mapped.sum()),
        "rms_m": float(np.sqrt(np.mean(err[mapped] ** 2))),
        "tilt_err_deg": plane_tilt_deg(emap.grid, err, mapped),
        "within_2sigma": float(np.mean(np.abs(err[mapped]) <= 2 * sig)),
        "datum_m": float(datum_m),
        "rms_ground_datum_m": float(np.sqrt(np.mean(err_g ** 2))),
        "within_2sigma_ground_datum": float(np.mean(np.abs(err_g) <= 2 * sig)),
        **seams(views, emap.grid.nx * emap.grid.ny),
    }
