"""The rover's path along the cliff edge: candidate positions set back into the safe side
(docs/algorithm.md §2, §3), and the geometry of an edge line's ends (its end direction, hooks).
``fsw.core.edge.edge`` re-exports :func:`edge_path`.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry import LineString, MultiLineString


class EdgeLines(Protocol):
    """What the offsetting needs of an edge model (``fsw.core.edge.edge.EdgeModel``)."""

    @property
    def empty(self) -> bool: ...

    @property
    def lines(self) -> MultiLineString: ...

    def barrier(self, extend_m: float) -> MultiLineString: ...


F64 = NDArray[np.float64]
END_TANGENT_M = 0.3  # length over which an edge line's end direction is taken (barrier)


def edge_path(model: EdgeLines, setback_m: float, spacing_m: float, extend_m: float = 0.0) -> F64:
    """Rover poses ``(x, y, yaw)`` along the edge, ``setback_m`` into the safe side (§2, §3).

    Each edge line is offset to its left; points closer than ``setback_m`` to any edge line
    (inside corners of the offset) are dropped. Yaw follows the edge direction. Where a line
    bends tighter than the setback its offset curve collapses; such a line is offset point by
    point along its normal smoothed over ``setback_m``. A path of fewer than three poses (an
    edge just glimpsed) is made again from the edge as the geofence takes it, continued
    ``extend_m`` past its ends (``EdgeModel.barrier``).
    """
    if model.empty:
        return np.zeros((0, 3))
    poses = _offset_poses(model.lines, model.lines, setback_m, spacing_m)
    if len(poses) < 3 and extend_m > 0:
        poses = _offset_poses(model.barrier(extend_m), model.lines, setback_m, spacing_m)
    return poses


def _offset_poses(lines: MultiLineString, edge: MultiLineString, setback_m: float,
                  spacing_m: float) -> F64:
    out = []
    for ln in lines.geoms:
        off = ln.offset_curve(setback_m, join_style="round")
        parts = [p for p in getattr(off, "geoms", [off]) if not p.is_empty and p.length > 0]
        if sum(p.length for p in parts) < 0.5 * ln.length:  # collapsed: offset point by point
            out.append(_normal_offset(ln, setback_m, spacing_m))
            continue
        for part in parts:
            n = max(2, int(np.floor(part.length / spacing_m)) + 1)
            s = np.linspace(0.0, part.length, n)
            out.append(np.column_stack([shapely.get_coordinates(
                shapely.line_interpolate_point(part, s)), _line_yaw(part, s, 1e-3)]))
    if not out:
        return np.zeros((0, 3))
    poses = np.concatenate(out)
    dist = shapely.distance(shapely.points(poses[:, :2]), edge)
    return np.asarray(poses[dist >= setback_m - 1e-6 - 0.01 * setback_m])


def _line_yaw(line: LineString, s: F64, half_m: float) -> F64:
    q = shapely.get_coordinates(shapely.line_interpolate_point(line, np.minimum(s + half_m, line.length)))
    r = shapely.get_coordinates(shapely.line_interpolate_point(line, np.maximum(s - half_m, 0.0)))
    t = q - r
    return np.asarray(np.arctan2(t[:, 1], t[:, 0]))


def _normal_offset(line: LineString, setback_m: float, spacing_m: float) -> F64:
    """Points ``setback_m`` to the left of ``line`` along its normal smoothed over ``setback_m``."""
    n = max(2, int(np.floor(line.length / spacing_m)) + 1)
    s = np.linspace(0.0, line.length, n)
    yaw = _line_yaw(line, s, setback_m)
    p = shapely.get_coordinates(shapely.line_interpolate_point(line, s))
    p = p + setback_m * np.column_stack([-np.sin(yaw), np.cos(yaw)])
    return np.column_stack([p, yaw])


def trim_hooks(c: F64) -> F64:
    """The polyline without end segments that turn back against its overall end direction
    (a fit's hook where the seen region ends)."""
    for _ in range(len(c)):
        if len(c) < 3:
            break
        ln = LineString(c)
        t0, t1 = (end_normal(ln, s)[0, ::-1] * (1.0, -1.0) for s in (True, False))
        if float(np.dot(c[1] - c[0], t0)) < 0:
            c = c[1:]
        elif float(np.dot(c[-1] - c[-2], t1)) < 0:
            c = c[:-1]
        else:
            break
    return c


def end_normal(ln: LineString, start: bool) -> F64:
    """(1, 2) unit left normal of the line's overall direction over its first (last)
    ``END_TANGENT_M``."""
    span = min(END_TANGENT_M, ln.length / 2.0)
    a = np.asarray(ln.interpolate(0.0 if start else ln.length - span).coords[0])
    b = np.asarray(ln.interpolate(span if start else ln.length).coords[0])
    d = b - a
    return np.array([[-d[1], d[0]]]) / max(float(np.hypot(*d)), 1e-12)
