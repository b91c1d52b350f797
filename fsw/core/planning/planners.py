"""The five mapping methods of the paper and an oracle, behind one interface (docs/algorithm.md §7).

``planner.next_view(state) -> CandidateView | None`` (None: nothing reachable to do), or
``planner.search(state)``, a generator that yields between bounded steps (a geofence check, a
chunk of rays, a block of ray samples, one tilt's field-of-view sums: a few ms each here) so
the executive can run the search in frame slack, and returns the view.

1. ``RasterPlanner(sweep=False)``: raster scan without yaw, set up once at the first call as
   a competent operator would. Row 1 runs along the edge path from the rover toward the
   longer remaining part, the mast fixed: pan square to the path toward the drop, lift at
   maximum, and the tilt that maximises the view's footprint on the expected floor (the ROI
   floor seen so far, or ``raster_floor_drop_m`` below the rover), steepened if needed so
   the edge lip stays in the image (each view also maps the edge to drive along). Spacing:
   the footprint's length along the path times ``1 - raster_overlap_frac`` (consecutive
   views just overlap), reduced if needed so the ``n_views`` steps fit in the region of
   interest. The path is the edge path as far as it is known, continued straight past its
   ends to where they leave the map (the operator scans the whole region, assuming the edge goes
   on); it is re-read at every call, so the stations follow the edge as it is revealed.
   Each station is one spacing on from the last one along the path; if the geofence
   refuses the move there, the station is the farthest path point toward it (0.05 m steps)
   that it allows, at least a quarter spacing on (the operator advances as far as is safe;
   that view reveals the edge ahead and the row goes on). When no such point exists (the
   reachable part of the path, or the path itself, ends) the row ends and the next row
   begins where the rover stands: back the other way along the path (the rover keeps its
   heading and backs up, so the pan stays toward the drop) at the next tilt band out (the
   band whose footprint overlaps the last one's across the path by ``raster_overlap_frac``
   of its width; bands end where one would add less than a quarter of the last band's
   width: the range limit), spaced by the band's along-path width where its new ground
   starts, less the overlap, reduced so the stations left (split evenly over the bands
   left) spread over the path to its far end. After the farthest band a new pass starts
   from the first band. So every one of the ``n_views`` steps is a view; the pointing
   within a row never changes (Method 1 has no yaw). If the geofence allows no move at all
   from where the rover stands, the rows shrink to mast-only views there.
2. ``RasterPlanner(sweep=True)``: raster scan with yaw: the same rows, with
   ``raster_pans_per_station`` pan views at each station, a pan step of
   ``hfov * (1 - overlap)`` around the same centre; stations spaced by the sweep's (union)
   footprint along the path the same way; the same number of views.
3. ``InformationPlanner(straight_edge=True)``: information-based, the edge path straightened
   to one segment (total least squares through the path points, spanning them).
4. ``InformationPlanner()``: information-based on the polygon edge's path.
5. ``InformationPlanner(use_interest=True)``: Method 4 with P_V pre-multiplied by the
   interest function.
Oracle: ``InformationPlanner`` rating with the true terrain (sigma ``oracle_sigma_m``) and the
true texture (a textureless cell is worth nothing): an upper bound for analysis.

Every raster station passes the geofence from the rover's pose (``motion_ok``), or is the
rover's pose itself. Information planners only rate reachable stations
(``view_candidates.path_stations``). No planner proposes a pose outside the mast limits.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Generator
from dataclasses import dataclass, field

import numpy as np

from fsw.core.planning.nbv import (
    MapLike,
)
from fsw.core.planning.view_candidates import (
    CandidateView,
    MotionCheck,
    Pose3,
)
from fsw.core.planning.visibility import F64
from fsw.core.steps import run_to_end

METHODS = ("1", "2", "3", "4", "5", "oracle")


@dataclass(frozen=True)
class PlannerState:
    """What a planner reads each step. ``path`` is the edge-following rover path (N, 2|3)."""

    map: MapLike
    rover: Pose3
    joints: Pose3
    path: F64
    motion_ok: MotionCheck
    edge_xy: F64 | None = None  # the fitted edge's points: which side the drop is on
    ground_z_m: float = 0.0
    sigma_loc_m: float = 0.0
    landmarks_xyz: F64 = field(default_factory=lambda: np.zeros((0, 3)))
    at_start: bool = False  # the rover has not left its start (every footprint it stood on is here)


SearchGen = Generator[None, None, CandidateView | None]


class Planner(ABC):
    """Common interface of the §7 methods."""

    name: str = ""

    def next_view(self, state: PlannerState) -> CandidateView | None:
        return run_to_end(self.search(state))

    @abstractmethod
    def search(self, state: PlannerState) -> SearchGen: ...
