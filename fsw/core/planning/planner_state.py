"""A next-view planner's state as plain data, for mission checkpoints (docs/algorithm.md §3, §7).

The information planners (Methods 3-5, oracle; docs/algorithm.md §3.2-§3.5) rate views on the map
alone: nothing to keep but their counters. The raster baselines (Methods 1 and 2, §7) follow a
plan made once at their first search: the tilt bands, the rows begun, the stations taken and
the place in a station's pan sweep. A resumed mission must continue that plan, not make a new
one from wherever the rover stands, so it is saved with the step's checkpoint and put back
into the planner the resumed run builds. Pure: JSON-able dicts in and out.
"""

from __future__ import annotations

from typing import Any

from fsw.core.planning.planners import Planner
from fsw.core.planning.raster_planners import RasterPlanner, _Row

_RASTER_PLAIN = ("spacing_m", "given", "_ready", "_lift", "_heading_dir", "_sweep_i")


def _pose(p: Any) -> tuple[float, float, float]:
    a, b, c = (float(v) for v in p)
    return (a, b, c)


def planner_state(planner: Planner) -> dict[str, Any]:
    """What ``planner`` must keep across a restart."""
    if not isinstance(planner, RasterPlanner):
        return {"kind": "information"}
    p = planner
    return {
        "kind": "raster",
        "name": p.name,
        **{k: getattr(p, k) for k in _RASTER_PLAIN},
        "bands": [list(b) for b in p.bands],
        "pans": list(p._pans),
        "last_xy": list(p._last_xy),
        "station": None if p._station is None else list(p._station),
        "rows": [{"direction": r.direction, "joints": [list(j) for j in r.joints], "spacing_m": r.spacing_m,
                  "stations": r.stations, "band": r.band, "taken": r.taken} for r in p.rows],
    }


def restore_planner(planner: Planner, state: dict[str, Any]) -> None:
    """Put ``planner_state`` back; ``ValueError`` if it belongs to another kind of planner."""
    kind = "raster" if isinstance(planner, RasterPlanner) else "information"
    if state.get("kind") != kind:
        raise ValueError(f"planner state of kind {state.get('kind')!r} for a {kind} planner")
    if not isinstance(planner, RasterPlanner):
        return
    if state["name"] != planner.name:
        raise ValueError(f"raster state of method {state['name']} for method {planner.name}")
    planner.spacing_m, planner.given = float(state["spacing_m"]), int(state["given"])
    planner._ready, planner._lift = bool(state["_ready"]), float(state["_lift"])
    planner._heading_dir, planner._sweep_i = float(state["_heading_dir"]), int(state["_sweep_i"])
    planner.bands = [(float(t), float(s)) for t, s in state["bands"]]
    planner._pans = [float(v) for v in state["pans"]]
    x, y = (float(v) for v in state["last_xy"])
    planner._last_xy = (x, y)
    planner._station = None if state["station"] is None else _pose(state["station"])
    planner.rows = [_Row(float(r["direction"]), [_pose(j) for j in r["joints"]], float(r["spacing_m"]),
                         int(r["stations"]), int(r["band"]), int(r["taken"])) for r in state["rows"]]
