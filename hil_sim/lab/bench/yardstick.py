"""The yardstick of ``safer-hil bench cycle``: a fixed workload timed in the same run as the cycle,
so cycle figures from different machines (or one machine under different load) compare.

The workload is the kind of work the sensing cycle does, on fixed seeded inputs that do not
depend on the flight code (a change to the pipeline never changes the yardstick): OpenCV SGBM
on a textured pair (stereo), a float Gaussian blur (the edge's ground surface), per-cell sums of
points (the merge), a Euclidean distance transform (the visibility prior), row sorts of ray
crossings, and row copies, table look-ups and sums of the P_V kernel's kind. Its CPU time on
this machine against ``yardstick_ref_s`` (config/budget.toml: its time on the reference machine,
the one ``cpu_factor`` is estimated against) scales a figure measured here to that machine:
``reference_s = here_s * yardstick_ref_s / yardstick_here_s``.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import cv2
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy import ndimage

SEED = 20260530


def _parts() -> list[tuple[str, Callable[[], object]]]:
    """The workload's parts, their inputs made once (seeded)."""
    rng = np.random.default_rng(SEED)
    left = cv2.GaussianBlur(rng.integers(0, 256, (240, 320), dtype=np.uint8), (3, 3), 0.8)
    right = np.roll(left, -12, axis=1)
    sgbm = cv2.StereoSGBM.create(minDisparity=0, numDisparities=64, blockSize=5, P1=200, P2=800,
                                 mode=cv2.StereoSGBM_MODE_SGBM)
    field = rng.normal(0.0, 0.05, (512, 512)).astype(np.float32)
    xyz = rng.uniform(0.0, 512.0, (200_000, 2))
    flat = (xyz[:, 1].astype(np.intp) * 512 + xyz[:, 0].astype(np.intp))
    weights = rng.uniform(0.5, 2.0, flat.size)
    holes = rng.random((256, 256)) < 0.7
    crossings = rng.uniform(0.0, 5.0, (256, 1200)).astype(np.float32)
    crossings[:, :600].sort(axis=1)
    crossings[:, 600:].sort(axis=1)
    samples = rng.uniform(0.0, 3000.0, 400_000).astype(np.float32)
    rows = sliding_window_view(samples, 160)
    base = rng.integers(0, samples.size - 160, 24576)
    table = np.sort(rng.normal(size=3840)).astype(np.float32)

    def pv_like() -> float:
        x = rows[base] * np.float32(0.7)
        np.clip(x, 0, table.size - 1, out=x)
        return float(np.einsum("ij,ij->i", np.take(table, x.astype(np.int32)), rows[base]).sum())

    return [
        ("sgbm", lambda: sgbm.compute(left, right)),
        ("blur", lambda: cv2.GaussianBlur(field, (0, 0), 6.0, borderType=cv2.BORDER_CONSTANT)),
        ("bincount", lambda: [np.bincount(flat, weights, 512 * 512) for _ in range(3)]),
        ("edt", lambda: ndimage.distance_transform_edt(holes)),
        ("sort", lambda: np.sort(crossings, axis=1, kind="stable")),
        ("pv", pv_like),
    ]


def yardstick_s(repeats: int = 5) -> float:
    """CPU seconds of one pass of the workload: the sum over its parts of each part's minimum
    over ``repeats`` passes (the least disturbed run of each)."""
    parts = _parts()
    best = [float("inf")] * len(parts)
    for _ in range(max(1, repeats)):
        for i, (_, fn) in enumerate(parts):
            c0 = time.process_time()
            fn()
            best[i] = min(best[i], time.process_time() - c0)
    return float(sum(best))
