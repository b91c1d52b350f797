"""Hierarchical interpolation order and predictor for the quadtree leaf values (docs/algorithm.md §6.5).

The predictive stage of the map codec visits the map's cells coarse to fine, like a
Laplacian pyramid: first cell ``(0, 0)``, then, for ``h = 2**(L-1), ..., 1``, the *centre*
points ``(odd*h, odd*h)`` predicted from their four diagonal neighbours at distance ``h``,
then the *edge* points ``(even*h, odd*h)`` and ``(odd*h, even*h)`` predicted from their four
axial neighbours. Every neighbour was visited in an earlier step, so each step is one
vectorised operation over all its points, and encoder and decoder see the same values.

A quadtree leaf's top-left cell (its *anchor*) is the first of its cells in this order,
because it lies on the coarsest lattice of all of them; the codec sends one residual per
known leaf, at its anchor, and every later cell of the leaf copies the leaf's value.

The predictor is edge-directed: of the two opposite neighbour pairs, take the mean of the
pair that agrees better (so a rock's rim is interpolated along it, not across it); at the
map border, the mean of what exists. Everything is integer arithmetic on lattice codes, so
prediction is bit-identical on every machine.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

I64 = NDArray[np.int64]


@dataclass(frozen=True)
class Step:
    """One vectorised step: flat indices of its points and of their four neighbours.

    Neighbours outside the map point at index ``ny * nx`` (a spare slot the caller keeps at
    0). ``nbr[0], nbr[1]`` and ``nbr[2], nbr[3]`` are the two opposite pairs; ``full`` marks
    points with all four neighbours and ``count`` how many they have.
    """

    pts: I64
    nbr: I64  # (4, n)
    full: NDArray[np.bool_]
    count: I64


def _grid(ys: I64, xs: I64, offsets: tuple[tuple[int, int], ...], shape: tuple[int, int]) -> Step:
    ny, nx = shape
    gy, gx = np.meshgrid(ys, xs, indexing="ij")
    yy, xx = gy.ravel(), gx.ravel()
    nbr = np.empty((4, yy.size), np.int64)
    ok = np.empty((4, yy.size), bool)
    for k, (dy, dx) in enumerate(offsets):
        y, x = yy + dy, xx + dx
        ok[k] = (y >= 0) & (y < ny) & (x >= 0) & (x < nx)
        nbr[k] = np.where(ok[k], y * nx + x, ny * nx)
    full: NDArray[np.bool_] = np.asarray(ok.all(axis=0))
    return Step(pts=yy * nx + xx, nbr=nbr, full=full, count=ok.sum(axis=0))


@lru_cache(maxsize=8)
def visit_order(shape: tuple[int, int]) -> tuple[Step, ...]:
    """The coarse-to-fine steps covering every cell of a map of ``shape`` exactly once."""
    ny, nx = shape
    L = int(max(0, int(np.ceil(np.log2(max(shape))))))
    steps = [Step(pts=np.zeros(1, np.int64), nbr=np.full((4, 1), ny * nx, np.int64),
                  full=np.zeros(1, bool), count=np.zeros(1, np.int64))]
    for s in range(L, 0, -1):
        h = 1 << (s - 1)
        odd_y, odd_x = np.arange(h, ny, 2 * h), np.arange(h, nx, 2 * h)
        even_y, even_x = np.arange(0, ny, 2 * h), np.arange(0, nx, 2 * h)
        diag = ((-h, -h), (h, h), (-h, h), (h, -h))
        axial = ((0, -h), (0, h), (-h, 0), (h, 0))
        for ys, xs, offs in ((odd_y, odd_x, diag), (even_y, odd_x, axial), (odd_y, even_x, axial)):
            if ys.size and xs.size:
                steps.append(_grid(ys, xs, offs, shape))
    return tuple(steps)


def predict(values: I64, step: Step) -> I64:
    """Edge-directed integer prediction of each point of ``step`` from ``values``.

    ``values`` has ``ny * nx + 1`` entries; the last is the out-of-map slot and must be 0.
    """
    v0, v1, v2, v3 = (values[step.nbr[k]] for k in range(4))
    pair_a = (v0 + v1 + 1) >> 1
    pair_b = (v2 + v3 + 1) >> 1
    directed = np.where(np.abs(v0 - v1) <= np.abs(v2 - v3), pair_a, pair_b)
    if step.full.all():
        return directed
    n = np.maximum(step.count, 1)
    mean_all = (2 * (v0 + v1 + v2 + v3) + n) // (2 * n)
    return np.where(step.full, directed, mean_all)
