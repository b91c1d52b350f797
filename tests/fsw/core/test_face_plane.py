"""The face plane's fit (``fsw.core.map.face_plane``, docs/algorithm.md §8.1) on synthetic
gravity maps of a cliff: which steep cells it takes for the face and when it refuses."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap
from fsw.core.map.face_plane import fit_face_plane

SLOPE = 70.0
NOMINAL = np.array([0.0, -math.sin(math.radians(SLOPE)), math.cos(math.radians(SLOPE))])


def _cliff(face_x: tuple[float, float] = (-2.0, 2.0), ramps: bool = False) -> ElevationMap:
    """A gravity map of a plateau (y > 0), a 70 deg face 3 m high (mapped only where ``face_x[0]
    <= x <= face_x[1]``: what early views hold of it) and a floor with steep-sided rocks; with
    ``ramps`` the floor is ramps rising at 50 deg toward +x and dropping back, steep ground that
    falls toward -x and outnumbers the face's cells."""
    rng = np.random.default_rng(1)
    grid = MapGrid(-2.0, -4.0, 0.04, 100, 125)
    x, y = grid.centers()
    run = 3.0 / math.tan(math.radians(SLOPE))
    z = np.where(y > 0, 0.0, np.where(-run < y, y * math.tan(math.radians(SLOPE)), -3.0))
    if ramps:
        z = np.where(y < -run - 0.2, z + math.tan(math.radians(50.0)) * np.mod(x, 0.3), z)
    for _ in range(12):  # boxes on the floor: steep sides facing every way
        cx, cy = rng.uniform(-1.8, 1.8), rng.uniform(-3.8, -run - 0.3)
        z = np.where((np.abs(x - cx) < 0.12) & (np.abs(y - cy) < 0.12), z + 0.3, z)
    known = ~((y <= 0) & (y >= -run) & ((x < face_x[0]) | (x > face_x[1])))
    m = ElevationMap(grid)
    m.z = np.where(known, z + rng.normal(0, 0.01, z.shape), np.nan)
    m.n[:] = known
    m.var[:] = np.where(known, 1e-4, np.inf)
    return m


def _off_deg(normal: np.ndarray) -> float:
    return math.degrees(math.acos(float(np.clip(normal @ NOMINAL, -1.0, 1.0))))


def test_the_face_among_steep_ground_that_falls_another_way() -> None:
    """Ramps on the floor hold more steep cells than the face, all falling toward -x: the face is
    the plane whose cells fall its own way, not a plane through the mean downhill direction."""
    f = fit_face_plane(_cliff(ramps=True))
    assert _off_deg(f.normal) < 2.0
    assert f.slope_deg == pytest.approx(SLOPE, abs=2.0)


def test_a_strip_of_face_is_not_yet_a_face() -> None:
    """With half a metre of the face mapped along its strike (beside ramps and rocks) no plane is
    accepted and the error says why; with the whole face mapped the same ground gives the face."""
    with pytest.raises(ValueError, match="no face to fit|not yet a face"):
        fit_face_plane(_cliff(face_x=(0.0, 0.5), ramps=True))
    with pytest.raises(ValueError, match=r"span 0\.5\d m along its strike"):
        fit_face_plane(_cliff(face_x=(0.0, 0.5)))
    assert _off_deg(fit_face_plane(_cliff()).normal) < 2.0
