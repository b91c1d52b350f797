"""Taut tethers and ground heights for many places at once (docs/algorithm.md §8).

The arithmetic of :mod:`fsw.core.team.tether` (bilinear heights, the ground profile under a
tether, the upper convex hull a taut tether follows, its length, contacts and pull), done
for a batch of tethers in a few array passes instead of a few dozen small ones per tether:
the planner judges thousands of lattice nodes and the bench settles the Cliff-bot with a
Jacobian of four tether states at every step. Every element goes through the same
operations in the same order as the one-at-a-time code, so the results are the same bit for
bit (``tests/fsw/core/team/test_tether_batch.py`` checks it against that code).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import MapGrid

F64 = NDArray[np.float64]
IntP = NDArray[np.intp]
ZMap = NDArray[np.float32 | np.float64]  # a 2.5D map: heights, NaN unknown


def heights_at(z: ZMap, grid: MapGrid, x: F64, y: F64) -> F64:
    """Bilinear heights at the points ``(x, y)`` between the four nearest cell centres (NaN
    when one is unknown, off the map, or the point is not finite)."""
    with np.errstate(invalid="ignore"):
        fx = (x - grid.x0) / grid.cell - 0.5
        fy = (y - grid.y0) / grid.cell - 0.5
        flx, fly = np.floor(fx), np.floor(fy)
        ok = (flx >= 0) & (flx < grid.nx - 1) & (fly >= 0) & (fly < grid.ny - 1)
        ix = np.where(ok, flx, 0).astype(np.intp)
        iy = np.where(ok, fly, 0).astype(np.intp)
        ax, ay = fx - flx, fy - fly
        q00 = np.asarray(z[iy, ix], np.float64)
        q01 = np.asarray(z[iy, ix + 1], np.float64)
        q10 = np.asarray(z[iy + 1, ix], np.float64)
        q11 = np.asarray(z[iy + 1, ix + 1], np.float64)
        h = (1 - ay) * ((1 - ax) * q00 + ax * q01) + ay * ((1 - ax) * q10 + ax * q11)
    return np.where(ok, h, np.nan)


def vector_norm(v: F64) -> float:
    """``np.linalg.norm`` of a 1-D vector, the same value (for a float64 vector it is the square
    root of ``v . v``) without its dispatch: the statics take a few hundred thousand a mission."""
    v = np.asarray(v)
    if v.dtype != np.float64 or v.ndim != 1:
        return float(np.linalg.norm(v))
    return math.sqrt(float(v.dot(v)))


def _ranges(lengths: IntP) -> tuple[IntP, IntP]:
    """For segments of ``lengths``: each element's segment and its position in it."""
    seg = np.repeat(np.arange(len(lengths)), lengths)
    starts = np.cumsum(lengths) - lengths
    return seg, np.arange(int(lengths.sum())) - starts[seg]


def upper_hulls(s: F64, h: F64, first: IntP, last: IntP) -> list[IntP]:
    """The upper convex hull of each run ``first[k]..last[k]`` (inclusive) of the points
    ``(s, h)`` (``s`` increasing in a run, both ends kept and finite, ``-inf`` for unknown
    ground between them), as indices into ``s``, increasing.

    QuickHull's upper half (the point farthest above each chord splits it), every run's
    chords in the same round: per chord the first point of the largest ``above`` wins, as
    ``argmax`` picks it, so the hull is the one-run-at-a-time QuickHull's."""
    verts: list[list[int]] = [[int(f)] for f in first]
    seg_i = np.asarray(first, np.intp)
    seg_j = np.asarray(last, np.intp)
    owner = np.arange(len(first))
    while len(seg_i):
        short = seg_j - seg_i < 2
        for k, j in zip(owner[short], seg_j[short], strict=True):
            verts[k].append(int(j))
        seg_i, seg_j, owner = seg_i[~short], seg_j[~short], owner[~short]
        if not len(seg_i):
            break
        n_in = seg_j - seg_i - 1
        which, pos = _ranges(n_in)
        idx = seg_i[which] + 1 + pos
        si, sj, hi, hj = s[seg_i][which], s[seg_j][which], h[seg_i][which], h[seg_j][which]
        above = (sj - si) * (h[idx] - hi) - (hj - hi) * (s[idx] - si)
        starts = np.cumsum(n_in) - n_in
        best = np.maximum.reduceat(above, starts)
        cand = np.where(above == best[which], pos, np.iinfo(np.intp).max)
        k_first = np.minimum.reduceat(cand, starts)
        split = best > 0.0
        for k, j in zip(owner[~split], seg_j[~split], strict=True):
            verts[k].append(int(j))
        m = seg_i[split] + 1 + k_first[split]
        seg_i = np.concatenate([seg_i[split], m])
        seg_j = np.concatenate([m, seg_j[split]])
        owner = np.concatenate([owner[split], owner[split]])
    return [np.asarray(sorted(v), np.intp) for v in verts]


def taut_tethers(z: ZMap, grid: MapGrid, ends_a: F64, ends_b: F64, step_m: float
                 ) -> list[tuple[float, F64, F64, bool]]:
    """The taut tether from each ``ends_a[k]`` (x y z, the anchor's exit) to ``ends_b[k]`` (the
    attachment point): its length, contacts (K, 3), the unit pull on ``b`` and whether it
    passes over ground the map does not know (:func:`fsw.core.team.tether.tether_path`)."""
    a = np.asarray(ends_a, float).reshape(-1, 3)
    b = np.asarray(ends_b, float).reshape(-1, 3)
    d = b[:, :2] - a[:, :2]
    spans = np.array([float(math.hypot(dx, dy)) for dx, dy in d])
    n = np.array([int(sp / step_m) for sp in spans], np.intp)
    # The ground profile of every tether (samples 1..n between the ends), one array pass.
    which, pos = _ranges(n)
    s = (pos + 1).astype(np.float64) * (spans / (n + 1))[which]
    ix = np.floor(((a[which, 0] + d[which, 0] * s / spans[which]) - grid.x0) / grid.cell)
    iy = np.floor(((a[which, 1] + d[which, 1] * s / spans[which]) - grid.y0) / grid.cell)
    inside = (ix >= 0) & (ix < grid.nx) & (iy >= 0) & (iy < grid.ny)
    h = np.asarray(z[np.where(inside, iy, 0).astype(np.intp), np.where(inside, ix, 0).astype(np.intp)], np.float64)
    known = inside & np.isfinite(h)
    h = np.where(known, h, -np.inf)
    unknown = np.bincount(which, weights=~known, minlength=len(n)) > 0
    # Each tether's points: its anchor end, its profile, its attachment end.
    m = n + 2
    first = np.cumsum(m) - m
    last = first + m - 1
    ss = np.empty(int(m.sum()))
    hh = np.empty(int(m.sum()))
    body = np.ones(len(ss), bool)
    body[first] = body[last] = False
    ss[first], ss[last], ss[body] = 0.0, spans, s
    hh[first], hh[last], hh[body] = a[:, 2], b[:, 2], h
    hulls = upper_hulls(ss, hh, first, last)
    out = []
    for k, idx in enumerate(hulls):
        sv, hv = ss[idx], hh[idx]
        seg = np.hypot(sv[1:] - sv[:-1], hv[1:] - hv[:-1])
        direction = d[k] / spans[k] if spans[k] > 0 else np.zeros(2)
        inner = idx[1:-1]
        contacts = np.empty((len(inner), 3))
        contacts[:, 0] = a[k, 0] + direction[0] * ss[inner]
        contacts[:, 1] = a[k, 1] + direction[1] * ss[inner]
        contacts[:, 2] = hh[inner]
        back = ss[last[k]] - ss[idx[-2]]  # from the hull vertex the last segment comes from
        pull = np.array([-direction[0] * back, -direction[1] * back, hh[idx[-2]] - b[k, 2]])
        norm = vector_norm(pull)
        out.append((float(seg.sum()), contacts, pull / norm if norm > 0 else pull, bool(unknown[k])))
    return out
