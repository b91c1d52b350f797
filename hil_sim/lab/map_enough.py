"""Whether the map was enough (docs/team.md, "Running a team mission"): the Cliff-bot's planner on
the received (reduced, decoded) map and on the full-resolution map of the same mission, given the
mission's configuration the legs as its mission plans them (:func:`compare_maps`): targets reached
on each, path length ratio, and the hazard and rock cells of the full map the received map shows
as safe. The paper's "relevant data" judged by the task it exists for.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import MapGrid
from fsw.core.team.climber_ground import ClimberConfig, ground_layers
from fsw.core.team.face_planner import plan_targets
from fsw.core.team.tether import TetherConfig
from fsw.sections import CliffbotMissionConfig

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class MapComparison:
    """Plans on the received map against plans on the full-resolution map (same start, targets)."""

    reasons_full: tuple[str, ...]
    reasons_received: tuple[str, ...]
    lengths_full_m: tuple[float, ...]
    lengths_received_m: tuple[float, ...]
    # cells the full map reads as a hazard (a rock or steep ground, grown by the footprint) or as
    # a rock (what a tether may not touch), known on the received map and not read so there
    hazard_cells_lost: int

    @property
    def verdicts_differ(self) -> int:
        return sum(1 for a, b in zip(self.reasons_full, self.reasons_received, strict=True) if bool(a) != bool(b))

    @property
    def path_ratio_max(self) -> float:
        """The largest received/full path length over targets reachable on both (NaN: none)."""
        r = [b / a for a, b in zip(self.lengths_full_m, self.lengths_received_m, strict=True)
             if math.isfinite(a) and math.isfinite(b) and a > 0]
        return max(r) if r else math.nan


def compare_maps(full_z: NDArray[np.floating], received_z: NDArray[np.floating], grid: MapGrid, anchors: F64,
                 start_xy: F64, targets_xy: F64, tcfg: TetherConfig, ccfg: ClimberConfig,
                 mission: CliffbotMissionConfig | None = None, error_bound_m: float = 0.0) -> MapComparison:
    """The same planner on both maps (module docstring). With ``mission``, the planner is the one
    the mission flies: each target's leg from the start (:meth:`fsw.tasks.cliffbot.legs.Route.plan`:
    the mission's margins, its ways between nodes judged as it drives them, the edges it cannot
    pass cut), on the received map with the codec's ``error_bound_m`` and on the full map with
    none; without it, the lattice search alone (:func:`plan_targets`, no margins, no ways)."""
    full = np.asarray(full_z, np.float64)
    got = np.asarray(received_z, np.float64)
    if mission is None:
        p_full = plan_targets(full, grid, anchors, start_xy, targets_xy, tcfg, ccfg)
        p_got = plan_targets(got, grid, anchors, start_xy, targets_xy, tcfg, ccfg)
        on_full, on_got = (p_full.reasons, p_full.lengths_m), (p_got.reasons, p_got.lengths_m)
    else:
        on_full = _legs(full, 0.0, grid, anchors, start_xy, targets_xy, tcfg, ccfg, mission)
        on_got = _legs(got, error_bound_m, grid, anchors, start_xy, targets_xy, tcfg, ccfg, mission)
    g_full = ground_layers(full, grid, ccfg, anchors=anchors)
    g_got = ground_layers(got, grid, ccfg, anchors=anchors)
    # A rock is lost too when it lies inside another's grown hazard (a tether may not touch it).
    lost = int((((g_full.hazard & ~g_got.hazard) | (g_full.rock & ~g_got.rock)) & np.isfinite(got)).sum())
    return MapComparison(tuple(on_full[0]), tuple(on_got[0]), tuple(on_full[1]), tuple(on_got[1]), lost)


def _legs(z: F64, error_bound_m: float, grid: MapGrid, anchors: F64, start_xy: F64, targets_xy: F64,
          tcfg: TetherConfig, ccfg: ClimberConfig, mission: CliffbotMissionConfig,
          ) -> tuple[tuple[str, ...], tuple[float, ...]]:
    """Each target's leg from the start as the mission plans it on ``z``: its reason and length."""
    from fsw.tasks.cliffbot.legs import Route

    route = Route(z, grid, error_bound_m, mission, tcfg, ccfg, np.asarray(anchors, float))
    got = [route.plan(np.asarray(start_xy, float), np.asarray(t, float))[0]
           for t in np.asarray(targets_xy, float).reshape(-1, 2)]
    return tuple(p.reasons[0] for p in got), tuple(float(p.lengths_m[0]) for p in got)
