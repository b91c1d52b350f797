"""Mars terrain from the Viking lander rock size-frequency model (docs/algorithm.md, "Mars terrain
statistics"; Golombek and Rapp 1997).

The fraction of the ground covered by rocks of diameter ``D`` metres or larger is

    F_k(D) = k * exp(-q(k) * D),    q(k) = 1.79 + 0.152 / k,

with ``k`` the total rock coverage (about 0.07 at Viking Lander 1, 0.16 at Viking Lander 2).
Differentiating, the number of rocks per square metre with diameter in ``[D, D + dD]`` is

    n(D) dD = k q exp(-q D) / (pi D^2 / 4) dD,

which diverges for small ``D``, so rocks are drawn between a lower cut-off ``d_min_m`` (by
default two grid cells: smaller rocks cannot be represented) and ``d_max_m``. Each rock is
given a height of about ``D / 2`` (uniform 0.4 D .. 0.6 D) and stamped on gently rolling
ground (fractal relief). :func:`viking_heightfield` is the public entry point used for the
paper's 32 test maps (docs/algorithm.md §6, data reduction against ``dH``) and by the ``mars``
scenario.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from hil_sim.world.noise import fractal_noise
from hil_sim.world.rocks import stamp_rocks

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

VL1_K = 0.07
"""Rock coverage at the Viking Lander 1 site."""
VL2_K = 0.16
"""Rock coverage at the Viking Lander 2 site."""


def q_of_k(k: float) -> float:
    """The exponent ``q(k) = 1.79 + 0.152 / k`` of the Viking model (per metre)."""
    _check_k(k)
    return 1.79 + 0.152 / k


def area_fraction_larger(d_m: F64 | float, k: float) -> F64:
    """``F_k(D)``: fraction of the area covered by rocks of diameter ``>= D`` metres."""
    return np.asarray(k * np.exp(-q_of_k(k) * np.asarray(d_m, float)), float)


def rocks_per_m2(k: float, d_min_m: float, d_max_m: float) -> float:
    """Expected number of rocks per square metre with ``d_min_m <= D <= d_max_m``."""
    d, cum = _cumulative_count(k, d_min_m, d_max_m)
    return float(cum[-1])


def sample_rock_diameters(
    area_m2: float, k: float, rng: np.random.Generator, d_min_m: float, d_max_m: float
) -> F64:
    """Diameters (metres) of the rocks on ``area_m2`` square metres: a Poisson count drawn
    from the model's expected number, each diameter drawn from ``n(D)`` by inverse CDF."""
    if k == 0.0:
        return np.zeros(0)
    d, cum = _cumulative_count(k, d_min_m, d_max_m)
    count = int(rng.poisson(cum[-1] * area_m2))
    u = rng.random(count) * cum[-1]
    return np.asarray(np.interp(u, cum, d), float)


def viking_heightfield(
    shape: tuple[int, int],
    cell_m: float,
    k: float,
    seed: int,
    *,
    relief_m: float = 0.05,
    relief_wavelength_m: float = 4.0,
    d_min_m: float | None = None,
    d_max_m: float = 2.0,
) -> F32:
    """A Mars-like elevation map: Viking-model rocks on gently rolling ground.

    Args:
        shape: ``(ny, nx)`` cells; array index ``[iy, ix]`` as in ``fsw.core.geometry.MapGrid``.
        cell_m: cell size in metres (e.g. 0.02 for a 512 x 512 map of 10.24 m).
        k: total rock coverage, ``0 <= k <= 0.5`` (0.07 Viking Lander 1, 0.16 Lander 2);
            ``k = 0`` gives the rolling ground alone.
        seed: random seed; the same arguments always give the same map.
        relief_m: standard deviation of the rolling ground (metres).
        relief_wavelength_m: longest wavelength of the rolling ground (metres).
        d_min_m: smallest rock diameter drawn (default: two cells, at least 1 cm).
        d_max_m: largest rock diameter drawn (metres).

    Returns:
        ``float32`` heights in metres, ``z`` up, mean ground level near 0. Rocks stand up to
        about ``D / 2`` above the local ground.
    """
    ny, nx = int(shape[0]), int(shape[1])
    if ny < 2 or nx < 2:
        raise ValueError(f"shape {shape} must be at least 2 x 2 cells")
    if not (cell_m > 0.0 and math.isfinite(cell_m)):
        raise ValueError(f"cell_m must be positive, got {cell_m}")
    _check_k(k, allow_zero=True)
    rng = np.random.default_rng(seed)
    ground = fractal_noise((ny, nx), cell_m, rng, beta=3.0,
                           min_wavelength_m=max(4 * cell_m, 0.2),
                           max_wavelength_m=relief_wavelength_m)
    height = np.ascontiguousarray(ground * np.float32(relief_m), dtype=np.float32)
    if k > 0.0:
        d_min = max(2.0 * cell_m, 0.01) if d_min_m is None else d_min_m
        d_max = max(d_max_m, 1.01 * d_min)
        place_viking_rocks(height, 0.0, 0.0, cell_m, k, rng, d_min, d_max)
    return height


def place_viking_rocks(
    height: F32,
    x0: float,
    y0: float,
    cell_m: float,
    k: float,
    rng: np.random.Generator,
    d_min_m: float,
    d_max_m: float,
    *,
    weight: F32 | None = None,
    rock_id: NDArray[np.int32] | None = None,
    first_id: int = 0,
) -> int:
    """Scatter Viking-model rocks over the grid ``height`` in place; returns how many.

    Rock centres are uniform over the grid plus a margin of ``d_max_m / 2`` (so coverage is
    even up to the borders). With ``weight`` (same shape, values in ``[0, 1]``) a rock is kept
    with the probability found under its centre: a local coverage ``k * weight``.
    """
    ny, nx = height.shape
    margin = 0.5 * d_max_m
    w_m, h_m = nx * cell_m + 2 * margin, ny * cell_m + 2 * margin
    d = sample_rock_diameters(w_m * h_m, k, rng, d_min_m, d_max_m)
    x = x0 - margin + rng.random(d.size) * w_m
    y = y0 - margin + rng.random(d.size) * h_m
    hgt = d * rng.uniform(0.4, 0.6, d.size)
    if weight is not None:
        ix = np.clip(((x - x0) / cell_m).astype(np.intp), 0, nx - 1)
        iy = np.clip(((y - y0) / cell_m).astype(np.intp), 0, ny - 1)
        keep = rng.random(d.size) < weight[iy, ix]
        x, y, d, hgt = x[keep], y[keep], d[keep], hgt[keep]
    order = np.argsort(-d)  # big rocks first, small ones may sit on them
    stamp_rocks(height, x0, y0, cell_m, x[order], y[order], d[order], hgt[order], rng,
                rock_id=rock_id, first_id=first_id)
    return int(d.size)


def _cumulative_count(k: float, d_min_m: float, d_max_m: float) -> tuple[F64, F64]:
    if not (0.0 < d_min_m < d_max_m):
        raise ValueError(f"need 0 < d_min_m < d_max_m, got {d_min_m}, {d_max_m}")
    q = q_of_k(k)
    d = np.geomspace(d_min_m, d_max_m, 4000)
    n = k * q * np.exp(-q * d) / (np.pi * d * d / 4.0)
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (n[1:] + n[:-1]) * np.diff(d))])
    return d, cum


def _check_k(k: float, allow_zero: bool = False) -> None:
    lo_ok = k >= 0.0 if allow_zero else k > 0.0
    if not (lo_ok and k <= 0.5 and math.isfinite(k)):
        raise ValueError(f"rock coverage k must be in {'[0' if allow_zero else '(0'}, 0.5], got {k}")
