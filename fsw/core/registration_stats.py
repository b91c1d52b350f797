"""Statistics of a view's registration (``fsw.core.registration``; ALGORITHM.md §5.1, issue 13):
the two halves of the overlap, the posterior with directions held at the prior, and the
reference cells' own placement error carried into the correction."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import MapGrid
from fsw.core.reference_frames import ReferenceFrames, about

F64 = NDArray[np.float64]
ALL, HEIGHT_TILT = [0, 1, 2, 3, 4, 5], [0, 1, 5]  # directions of (dtheta, dt) a fit may move


def halves(xy: F64) -> NDArray[np.bool_]:
    """The first of two spatially disjoint halves of the points: split at the median of
    their horizontal principal axis (the long way across the overlap)."""
    c = xy - xy.mean(axis=0)
    _, vec = np.linalg.eigh(c.T @ c)
    s = c @ vec[:, -1]
    return np.asarray(s < np.median(s))


def posterior(N: F64, P_inv: F64, S: F64, free: list[int]) -> tuple[F64, F64]:
    """The correction's covariance (6x6) and ``C_f`` (the free block given the rest): with
    directions ``h`` held at the prior, the free estimate shifts by ``K dh``, ``K = -C_f
    (N_fh + P^-1_fh)``, when they are off by ``dh ~ (0, S_hh)``, so its covariance is
    ``C_f + K S_hh K^T`` and the held ones keep ``S_hh``."""
    f = np.ix_(free, free)
    Cf = np.linalg.inv(N[f] + P_inv[f])
    Cf = 0.5 * (Cf + Cf.T)
    held = [i for i in range(6) if i not in free]
    if not held:
        return Cf, Cf
    fh, hh = np.ix_(free, held), np.ix_(held, held)
    K = -Cf @ (N[fh] + P_inv[fh])
    C = np.zeros((6, 6))
    C[f] = Cf + K @ S[hh] @ K.T
    C[fh] = K @ S[hh]
    C[np.ix_(held, free)] = C[fh].T
    C[hh] = S[hh]
    return 0.5 * (C + C.T), Cf


def reference_covariance(J: F64, w: F64, scale: float, Cf: F64, free: list[int], p: F64, centre: F64,
                         grid: MapGrid, frames: ReferenceFrames) -> F64:
    """The correction's error from the reference's own placement (``J``, ``w``, ``p``: the used
    points' Jacobian rows, weights and world positions; ``scale`` the ``n_eff`` share): the cells a view aligns to
    are displaced by the pose error ``delta_k`` of the view ``k`` that mapped them (a rigid
    motion, :mod:`fsw.core.reference_frames`), and the fit follows its points there:
    ``dd = C sum_k N_k delta_k`` (``N_k``: the normal matrix of the points on view ``k``'s
    cells, ``C`` the posterior), so ``Cov = sum_k C N_k Sigma_k N_k C`` with ``Sigma_k`` the
    source view's merged pose covariance about this view's centre (sources taken independent;
    with directions held at the prior, ``C_f N_k[f, :]`` moves the free ones only)."""
    iy, ix, inside = grid.cell_index(p[:, 0], p[:, 1])
    src = np.where(inside, frames.sources(np.where(inside, iy * grid.nx + ix, 0)), -1)
    out = np.zeros((6, 6))
    for k in np.unique(src[src >= 0]):
        m = src == k
        Nk = (J[m] * w[m, None]).T @ J[m] * scale
        G = np.zeros((6, 6))
        G[free] = Cf @ Nk[free]
        out += G @ about(frames.covs[int(k)], frames.centres[int(k)], centre) @ G.T
    return 0.5 * (out + out.T)
