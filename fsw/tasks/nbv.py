"""The next-view task: runs the configured planner's search as a slack job (docs/algorithm.md §3).

The mission sequencer publishes a ``PlannerState`` on ``nbv.request``; this task resumes the
planner's search generator in frame slack (one camera centre per slice) and publishes the
chosen ``CandidateView`` (or ``None``: nothing reachable worth doing) on ``nbv.result``.

The edge search (docs/algorithm.md §2: the edge is found before the rover drives along it): while
no edge is fitted (the views from the start did not reach the drop), there is no edge path for
the raster baselines (Methods 1, 2) to follow; their views are then chosen by expected new
information (Method 4's rating, ``fsw.core.planning.info_planners``) among the edge search's stations
(``fsw.core.planning.view_candidates.search_stations_steps``), and the raster begins once an edge is
fitted. Methods 3-5 and the oracle search those stations themselves.
"""

from __future__ import annotations

import math
from typing import ClassVar

from fsw.core.planning.info_planners import InformationPlanner
from fsw.core.planning.methods import make_planner
from fsw.core.planning.planner_state import planner_state, restore_planner
from fsw.core.planning.planners import Planner, PlannerState, SearchGen
from fsw.core.planning.view_candidates import CandidateView
from fsw.framework.jobs import JobHandle
from fsw.framework.telemetry import Channel, EventDef, Severity
from fsw.tasks.base import FlightTask
from fsw.tasks.messages import NBV_REQUEST, NBV_RESULT
from fsw.tasks.mission_state import restore_into
from fsw.tasks.state_json import JsonObject, get_int, get_opt_object


class NbvTask(FlightTask):
    KIND: ClassVar[str] = "nbv"
    RATE_HZ: ClassVar[tuple[float, float]] = (5.0, 50.0)  # its timeouts and moves assume ~10 Hz
    DOC: ClassVar[str] = "Next-view selection by expected new information (slack job)."
    CHANNELS = (
        Channel("searches", "count"),
        Channel("search_ms", "ms", doc="busy time of the last search"),
        Channel("search_slices", "count"),
        Channel("best_info_bits", "bit", doc="H of the chosen view (Eq 3)"),
        Channel("expected_new_cells", "cells"),
        Channel("best_utility", ""),
    )
    EVENTS = (
        EventDef(
            "VIEW_CHOSEN",
            Severity.ACTIVITY_LO,
            "next view ({x:.2f}, {y:.2f}, {yaw_deg:.0f} deg) pan {pan_deg:.0f} tilt {tilt_deg:.0f}: "
            "H {bits:.0f} bit, {cells:.0f} cells expected",
        ),
        EventDef("NO_VIEW", Severity.ACTIVITY_HI, "no reachable view worth taking"),
        EventDef("SEARCH_FAILED", Severity.WARNING_HI, "view search failed: {error}", throttle=5),
    )

    def setup(self) -> None:
        self.planner: Planner | None = None
        self._edge_search: InformationPlanner | None = None  # Methods 1, 2 while no edge is fitted
        self.requests = self.subscribe(NBV_REQUEST, depth=1, policy="drop_oldest")
        self.job: JobHandle | None = None
        self.searches = 0
        self._planner_restore: JsonObject | None = None
        restore_into(self)  # a resumed mission (fsw.tasks.mission_state)

    def checkpoint_state(self) -> JsonObject:
        """The search count and the planner's plan (``fsw.core.planning.planner_state``)."""
        planner = None if self.planner is None else planner_state(self.planner)
        return {"searches": self.searches, "planner": planner or self._planner_restore}

    def restore_state(self, st: JsonObject) -> None:
        self.searches = get_int(st, "searches")
        self._planner_restore = get_opt_object(st, "planner")  # applied when the planner is built

    def run(self, frame: int) -> None:
        if self.job is not None and self.job.done:
            self._finish(self.job)
            self.job = None
        if self.job is None:
            state: PlannerState | None = self.requests.get()
            if state is not None:
                self.job = self.submit_job(self._search(state), "search")

    def _search(self, state: PlannerState) -> SearchGen:
        if self.planner is None:  # built on first use: the bench injects the oracle's truth late
            cfg = self.ctx.cfg
            truth = self.ctx.res.oracle_truth  # only the bench has it (oracle)
            self.planner = make_planner(
                cfg.mission.method,
                cfg.nbv.max_steps,
                cfg.nbv,
                cfg.camera,
                cfg.mast,
                truth_z_m=None if truth is None else truth.z_m,
                textured=None if truth is None else truth.textured,
            )
            if self._planner_restore is not None:
                restore_planner(self.planner, self._planner_restore)
                self._planner_restore = None
        if len(state.path) < 2 and not isinstance(self.planner, InformationPlanner):
            if self._edge_search is None:
                cfg = self.ctx.cfg
                self._edge_search = InformationPlanner("search", cfg.nbv, cfg.camera, cfg.mast)
            return (yield from self._edge_search.search(state))
        return (yield from self.planner.search(state))

    def _finish(self, h: JobHandle) -> None:
        self.searches += 1
        self.tlm("searches", self.searches)
        self.tlm("search_ms", h.busy_s * 1e3)
        self.tlm("search_slices", h.slices)
        if h.error is not None:
            self.event("SEARCH_FAILED", error=f"{type(h.error).__name__}: {h.error}")
            self.publish(NBV_RESULT, None)
            return
        view: CandidateView | None = h.result
        if view is None:
            self.event("NO_VIEW")
        else:
            self.tlm("best_info_bits", view.info_bits)
            self.tlm("expected_new_cells", view.expected_new_cells)
            self.tlm("best_utility", view.utility)
            self.event(
                "VIEW_CHOSEN",
                x=view.rover[0],
                y=view.rover[1],
                yaw_deg=math.degrees(view.rover[2]),
                pan_deg=math.degrees(view.joints[0]),
                tilt_deg=math.degrees(view.joints[1]),
                bits=view.info_bits,
                cells=view.expected_new_cells,
            )
        self.publish(NBV_RESULT, view)
