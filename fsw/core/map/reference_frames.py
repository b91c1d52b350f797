"""Which view's pose put each map cell where it is (docs/algorithm.md §5.1, §1.2; issue 13).

A map cell is as well placed as the pose of the view that measured it. Its variance says how
well its *height* is known, but not where the cell is horizontally: a view merged with a
4 deg / 15 cm pose error on gentle ground gives cells of small vertical variance that are
15 cm out of place. A view registered against them inherits that error, and a covariance
computed from the cell variances alone does not say so (issue 13: accepted views 6-10 cm off
with a stated 0.7-1.2 cm).

So the registration needs, for its reference points, the pose error of the views that mapped
them. This keeps, per map cell, the index of the view whose pose error displaces that cell
least (``owner``; fused cells are dominated by their best view), and per view its camera
centre and merged 6x6 pose covariance (the ``fsw.core.localization.localization`` convention: a rotation
about the world axes through the centre, then a translation). A view's pose error is a rigid
motion of the cells it placed; expressed about another centre ``c2`` the same motion has the
translation ``dt + dtheta x (c2 - c)`` (:func:`about`).
"""

from __future__ import annotations

import base64
import zlib
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fsw.core.localization.localization import skew

F64 = NDArray[np.float64]


def about(cov: F64, centre: F64, new_centre: F64) -> F64:
    """A rigid-motion covariance about ``centre`` expressed about ``new_centre``."""
    A = np.eye(6)
    A[3:, :3] = -skew(np.asarray(new_centre, np.float64) - np.asarray(centre, np.float64))
    out = A @ np.asarray(cov, np.float64) @ A.T
    return 0.5 * (out + out.T)


class ReferenceFrames:
    """The map's cells' source views (reset with the map)."""

    def __init__(self, shape: tuple[int, int]) -> None:
        self.shape = shape
        self.clear()

    def clear(self) -> None:
        self.owner = np.full(self.shape, -1, np.int32)
        self.score = np.full(self.shape, np.inf, np.float32)  # displacement variance at the cell, m^2
        self.centres: list[F64] = []
        self.covs: list[F64] = []

    def add(self, cells: NDArray[np.integer], xyz: F64, centre: F64, cov: F64) -> None:
        """A merged view: the flat indices of the cells it measured, their points ``xyz``
        (cell centre and mean height), its camera centre and merged pose covariance. It owns
        each cell it displaces less than the cell's present owner (kept only if it owns one)."""
        cov = np.asarray(cov, np.float64)
        if cov.shape != (6, 6) or not np.isfinite(cov).all() or len(cells) == 0:
            return
        c = np.asarray(centre, np.float64)
        lever = np.asarray(xyz, np.float64) - c
        # displacement of a cell by (dtheta, dt): dtheta x lever + dt = [-lever]x dtheta + dt
        A = np.zeros((len(cells), 3, 6))
        A[:, :, :3] = -skew(lever)
        A[:, :, 3:] = np.eye(3)
        score = np.einsum("nij,jk,nik->n", A, cov, A)
        flat_owner, flat_score = self.owner.reshape(-1), self.score.reshape(-1)
        idx = np.asarray(cells, np.intp)
        better = np.isfinite(score) & (score < flat_score[idx])
        if not better.any():
            return
        k = len(self.covs)
        flat_owner[idx[better]] = k
        flat_score[idx[better]] = score[better]
        self.centres.append(c.copy())
        self.covs.append(0.5 * (cov + cov.T))

    def sources(self, cells: NDArray[np.integer]) -> NDArray[np.int32]:
        """The owning view of each flat cell index (-1: none known)."""
        return np.asarray(self.owner.reshape(-1)[np.asarray(cells, np.intp)], np.int32)

    # -- checkpoint (a resumed mission) -------------------------------------------------------
    def state(self) -> dict[str, Any]:
        return {"owner": base64.b64encode(zlib.compress(self.owner.astype("<i4").tobytes())).decode("ascii"),
                "score": base64.b64encode(zlib.compress(self.score.astype("<f4").tobytes())).decode("ascii"),
                "centres": [c.tolist() for c in self.centres], "covs": [c.tolist() for c in self.covs]}

    def restore(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state`; anything missing or of the wrong size leaves no sources."""
        self.clear()
        try:
            owner = np.frombuffer(zlib.decompress(base64.b64decode(state["owner"])), "<i4").reshape(self.shape)
            score = np.frombuffer(zlib.decompress(base64.b64decode(state["score"])), "<f4").reshape(self.shape)
            centres = [np.asarray(c, np.float64).reshape(3) for c in state["centres"]]
            covs = [np.asarray(c, np.float64).reshape(6, 6) for c in state["covs"]]
        except (KeyError, TypeError, ValueError, zlib.error):
            return
        if len(centres) != len(covs) or int(owner.max(initial=-1)) >= len(covs):
            return
        self.owner, self.score = owner.astype(np.int32), score.astype(np.float32)
        self.centres, self.covs = centres, covs
