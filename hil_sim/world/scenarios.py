"""``load_scenario``: build (and cache) the :class:`World` a scenario spec names.

Worlds are deterministic for ``(spec, seed)`` and read-only, so one cached instance is
shared by every caller in a process (a lockstep run, the renderer and the tests).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numpy.typing import NDArray

from hil_sim.world.config import ScenarioConfig, ScenarioError, load_scenario_config
from hil_sim.world.world import World


def load_scenario(spec: str, seed: int | None = 0) -> World:
    """The world for ``spec`` (``lab``, ``cliff``, ``mars``, ``file:PATH``, a ``.toml`` path,
    each optionally followed by ``?key=value&...`` overrides) built with ``seed``.

    ``seed=None`` takes the scenario file's default seed. Raises :class:`ScenarioError` or
    ``fsw.framework.params.ConfigError`` (both ``ValueError``) with a one-line reason on bad input.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise ScenarioError("empty scenario spec (try: lab, cliff, mars, file:PATH)")
    if seed is not None and (not isinstance(seed, int) or seed < 0):
        raise ScenarioError(f"seed must be a non-negative integer, got {seed!r}")
    cfg, _ = load_scenario_config(spec)
    return _build_cached(spec.strip(), cfg.scenario.seed if seed is None else seed)


@functools.lru_cache(maxsize=8)
def _build_cached(spec: str, seed: int) -> World:
    cfg, _ = load_scenario_config(spec)
    return build_world(cfg, seed)


def build_world(cfg: ScenarioConfig, seed: int) -> World:
    """Build the world for an already validated scenario config (no caching)."""
    kind = cfg.scenario.kind
    if kind == "lab":
        from hil_sim.world.lab import build_lab

        return build_lab(cfg, seed)
    if kind == "cliff":
        from hil_sim.world.cliff import build_cliff

        return build_cliff(cfg, seed)
    if kind == "mars":
        from hil_sim.world.mars_scene import build_mars

        return build_mars(cfg, seed)
    if kind == "file":
        from hil_sim.world.dem import build_from_dem

        return build_from_dem(cfg, seed)
    if kind == "terrain":
        from hil_sim.world.terrain import build_terrain

        return build_terrain(cfg, seed)
    if kind == "cliff_team":
        from hil_sim.world.cliff_team import build_cliff_team

        return build_cliff_team(cfg, seed)
    raise ScenarioError(f"unknown scenario kind {kind!r}")  # config validation prevents this


def footprint_gap(edge_xy: NDArray[np.float64], x: float, y: float, yaw: float) -> float:
    """Least horizontal distance (m) from the rover's footprint at ``(x, y, yaw)`` (a rectangle
    of ``terrain.FOOTPRINT_HALF_LENGTH_M`` by ``FOOTPRINT_HALF_WIDTH_M`` about its centre) to the
    edge polyline's points; inf without an edge."""
    from hil_sim.world.terrain import FOOTPRINT_HALF_LENGTH_M, FOOTPRINT_HALF_WIDTH_M

    if len(edge_xy) == 0:
        return math.inf
    dx, dy = edge_xy[:, 0] - x, edge_xy[:, 1] - y
    u, v = math.cos(yaw) * dx + math.sin(yaw) * dy, -math.sin(yaw) * dx + math.cos(yaw) * dy
    out_u = np.maximum(np.abs(u) - FOOTPRINT_HALF_LENGTH_M, 0.0)
    out_v = np.maximum(np.abs(v) - FOOTPRINT_HALF_WIDTH_M, 0.0)
    return float(np.hypot(out_u, out_v).min())


def start_near_edge(spec: str, bearing_deg: float, distance_m: float, along_m: float = 0.0,
                    seed: int = 0) -> tuple[str, float]:
    """``spec`` with its rover start moved beside the world's true edge (a real DEM through
    ``file:``, or any scenario with an edge whose start the spec may set), and the footprint's
    measured gap to the edge (m).

    The start goes to the edge point nearest the scenario's own start, moved ``along_m`` along
    the edge (plateau on the left: positive is with the plateau on the left); the rover faces so
    that the edge lies at ``bearing_deg`` from its heading (0 ahead, -90 on its right), its
    footprint ``distance_m`` from the local edge line (its bumper when ahead, its wheels when
    right, a corner when diagonal), then corrected twice by the gap measured to the edge polyline
    (:func:`footprint_gap`: a curved edge comes closer than its tangent). ScenarioError when the
    world has no edge or the start would leave the plateau."""
    from hil_sim.world.terrain import FOOTPRINT_HALF_LENGTH_M, FOOTPRINT_HALF_WIDTH_M

    world = load_scenario(spec, seed)
    edge = np.asarray(world.edge_xy, np.float64)
    if len(edge) < 3:
        raise ScenarioError(f"{spec}: the world has no edge to place a start beside")
    sx, sy, _ = world.rover_start
    seg = np.hypot(*np.diff(edge, axis=0).T)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    s0 = float(arc[int(np.argmin(np.hypot(edge[:, 0] - sx, edge[:, 1] - sy)))]) + along_m
    if not 0.3 <= s0 <= arc[-1] - 0.3:
        raise ScenarioError(f"{spec}: {along_m:g} m along the edge leaves it (its length is {arc[-1]:.1f} m)")
    p = np.array([np.interp(s0, arc, edge[:, k]) for k in (0, 1)])
    a, b = (np.array([np.interp(s0 + d, arc, edge[:, k]) for k in (0, 1)]) for d in (-0.3, 0.3))
    t = (b - a) / max(float(np.hypot(*(b - a))), 1e-12)
    left = np.array([-t[1], t[0]]) * world.safe_side_sign  # toward the plateau
    rel = math.radians(bearing_deg)
    yaw = math.atan2(-left[1], -left[0]) - rel  # the edge (toward -left) at the bearing
    yaw = math.atan2(math.sin(yaw), math.cos(yaw))
    reach = FOOTPRINT_HALF_LENGTH_M * abs(math.cos(rel)) + FOOTPRINT_HALF_WIDTH_M * abs(math.sin(rel))
    offset = reach + distance_m
    for _ in range(3):
        c = p + offset * left
        gap = footprint_gap(edge, float(c[0]), float(c[1]), yaw)
        offset += distance_m - gap
    c = p + offset * left
    gap = footprint_gap(edge, float(c[0]), float(c[1]), yaw)
    if not bool(world.on_plateau(float(c[0]), float(c[1]))):
        raise ScenarioError(f"{spec}: the start ({c[0]:.2f}, {c[1]:.2f}) beside the edge is off the plateau")
    sep = "&" if "?" in spec else "?"
    placed = (f"{spec}{sep}rover_start.x_m={c[0]:.3f}&rover_start.y_m={c[1]:.3f}"
              f"&rover_start.yaw_deg={math.degrees(yaw):.1f}")
    return placed, gap
