"""Statistics of a view's registration (``fsw.core.registration.registration``; docs/algorithm.md §5.1, issue 13):
the two halves of the overlap, the posterior with directions held at the prior, and the
reference cells' own placement error carried into the correction."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import MapGrid
from fsw.core.map.reference_frames import ReferenceFrames, about

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


def reference_covariance(N: F64, Cf: F64, free: list[int], p: F64, centre: F64, grid: MapGrid,
                         frames: ReferenceFrames) -> F64:
    """The correction's error from the reference's own placement (``N``: the fit's normal
    matrix, ``p``: the used points' world positions): the cells a view aligns to are displaced
    by the pose error ``delta`` of the views that mapped them (a rigid motion,
    :mod:`fsw.core.map.reference_frames`), and the fit follows its points there: ``dd = C N delta``
    (``C`` the posterior; with directions held at the prior, ``C_f N[f, :]`` moves the free
    ones only), so ``Cov = C N Sigma N C``. ``Sigma`` is the sources' merged pose covariance
    about this view's centre, averaged over the used points (each point's cell's source). The
    sources are taken as one common error, not independent ones: the views of a station
    share the body's pose error and each station is placed from the last, and independent
    sources would let opposite leverage of two strips add up beyond either's error."""
    iy, ix, inside = grid.cell_index(p[:, 0], p[:, 1])
    src = np.where(inside, frames.sources(np.where(inside, iy * grid.nx + ix, 0)), -1)
    if not (src >= 0).any():
        return np.zeros((6, 6))
    ks, counts = np.unique(src[src >= 0], return_counts=True)
    sigma = sum(c * about(frames.covs[int(k)], frames.centres[int(k)], centre) for k, c in zip(ks, counts, strict=True))
    sigma = sigma / len(src)  # a point on a cell of no known source adds none
    G = np.zeros((6, 6))
    G[free] = Cf @ N[free]
    out = G @ sigma @ G.T
    return np.asarray(0.5 * (out + out.T))
