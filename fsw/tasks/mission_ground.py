"""The mission's moves over unfamiliar ground and its planning inputs (docs/algorithm.md §2, §3;
issue 13 item 3): a mixin of :class:`fsw.tasks.mission.MissionTask`.

- The geofence (``fsw.core.edge.geofence``) is set on the latest edge fit, the latest map (which
  ground is known) and the rover's own footprint (safe, known ground) before every check.
- Planners rate stations with the edge check alone; the mission then checks the whole move.
  A move over unknown ground is preceded by looks at that ground from where the rover stands
  (``fsw.core.edge.look``), part of the same imaging step: each look aims at the unknown cells of
  the whole swept footprint nearest the rover (the turn in place, the drive, the final turn),
  and the rover looks again at what is left while a look still maps some of it, up to
  ``mission.max_looks_per_move`` looks. A move still refused is driven part of the way: the
  pose nearest the station, among the points along the planned drive (turn, then drive) and
  the points straight ahead or behind (no turn: a turn in place sweeps the corners of the
  rover over ground beside and behind it), that the geofence allows; if no part of it is
  allowed, the step's view is taken from where the rover stands. The reason is kept per step
  (``stays``).
- The geofence work of a move (setting the fence, checking the move, the unknown ground it
  would sweep, the part-way search) runs as a slack job, one fence set-up or
  one check a slice (``_in_slack``); the mission's activations wait for it and then go on
  with its result. Done in the foreground it took 10-50 ms an activation (up to 590 ms for a
  part-way search on lab seed 2), 0.3-1.5 s on a flight computer 30x slower (issue 15).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Generator
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import shapely
from numpy.typing import NDArray

from fsw.core.edge.edge import EdgeModel, edge_path
from fsw.core.edge.geofence import Geofence, Verdict, goto_legs
from fsw.core.edge.look import look_joints
from fsw.core.planning.planners import PlannerState
from fsw.core.planning.view_candidates import CandidateView
from fsw.framework.jobs import JobHandle
from fsw.tasks.base import FlightTask
from fsw.tasks.messages import MapUpdate, NavPose
from fsw.tasks.mission_state import MissionPhase

Pose3 = tuple[float, float, float]
MIN_MOVE_M = 0.1  # stations closer than this (and turned less than MIN_TURN_RAD) are "here"
MIN_TURN_RAD = math.radians(10.0)
LOOK_DEPTH_M = 0.6  # a look aims at the unknown ground within this of the nearest unknown cell
PART_STEP_M = 0.05  # part-way moves are tried every this far along the way


@dataclass
class FenceJob:
    """The mission's geofence work in progress as a slack job, and what to do with its result."""

    handle: JobHandle
    then: Callable[[JobHandle], None]  # called with the finished job


class GroundAwareMission(FlightTask):
    """Needs the MissionTask attributes: ctx, geofence, latest, edge, nav, view, pending,
    step, looks, stays, _looked, _look_n, _look_left; and its event and _start_point methods."""

    geofence: Geofence
    latest: MapUpdate | None
    edge: EdgeModel | None
    nav: NavPose | None
    view: CandidateView | None
    pending: list[CandidateView]
    step: int
    looks: int
    edge_violations: int
    stays: list[str]
    _looked: Pose3 | None  # the station the last looks were for
    _look_n: int  # looks taken for it
    _look_left: int  # its unknown swept cells at the last look
    _looked_from: Pose3 | None
    fence_job: FenceJob | None

    if TYPE_CHECKING:  # provided by Task and MissionTask (stubs here would shadow them)
        def _goto(self, new: MissionPhase) -> None: ...

        def _request(
            self,
            kind: str,
            target: tuple[float, float, float] | None = None,
            joints: tuple[float, float, float] | None = None,
        ) -> None: ...

        def _start_point(self) -> None: ...

        def _enter_safe(self, reason: str) -> None: ...

    def _in_slack(self, work: Generator[None, None, object], then: Callable[[JobHandle], None]) -> None:
        """Run geofence ``work`` as a slack job; ``then(job)`` in the mission's first
        activation after it ends, ``job.result`` its result (the module docstring)."""
        self.fence_job = FenceJob(self.submit_job(work, "geofence"), then)

    def _fence_job_pending(self) -> bool:
        """True while the mission waits for its geofence job; a finished one is taken up here
        (its continuation, or SAFE with the reason if the job failed)."""
        job = self.fence_job
        if job is None:
            return False
        if not job.handle.done:
            return True
        self.fence_job = None
        if job.handle.error is not None:
            self._enter_safe(f"geofence work failed: {type(job.handle.error).__name__}: {job.handle.error}")
        else:
            job.then(job.handle)
        return True

    def _cancel_fence_job(self) -> None:
        if self.fence_job is not None:
            self.fence_job.handle.cancel()
            self.fence_job = None

    def _move_steps(self, here: Pose3, there: Pose3) -> Generator[None, None, tuple[Verdict, NDArray[np.float64]]]:
        """The fence set up, the move checked and, if refused over unknown ground, that ground
        (one slice each)."""
        self._fence(here)
        yield
        verdict = self.geofence.check(here, there)
        if verdict.allowed or "unknown ground" not in verdict.reason:
            return verdict, np.zeros((0, 2))
        yield
        return verdict, self.geofence.unknown_points(here, there)

    def _move_checked(self, here: Pose3, there: Pose3, checked: tuple[Verdict, NDArray[np.float64]]) -> None:
        verdict, unknown = checked
        if verdict.allowed:
            self._goto(MissionPhase.MOVE)
            self._request(kind="goto", target=there)
        else:
            self._refused(here, there, verdict.reason, unknown)

    def _refused(self, here: Pose3, there: Pose3, reason: str, unknown: NDArray[np.float64]) -> None:
        """The geofence refused the move: over unknown ground, look at it (see the module
        docstring); otherwise drive part of the way, as far as the geofence allows; otherwise
        take the step's view from here. Never a crossing, never a stall."""
        assert self.view is not None
        if "unknown ground" in reason and self._look_at_swept(here, there, unknown):
            return
        self.edge_violations += 1  # a refusal that stands (a look is not one)
        self.event("GEOFENCE", x=there[0], y=there[1], reason=reason)
        self._in_slack(self._part_way_steps(here, there),
                       lambda job: self._part_way_done(here, there, reason, job.result))

    def _part_way_done(self, here: Pose3, there: Pose3, reason: str, part: Pose3 | None) -> None:
        assert self.view is not None
        pan, tilt, lift = self.view.joints
        if part is None:
            self.stays.append(f"step {self.step}: {reason}")
            turn = math.remainder(pan + there[2] - here[2], math.tau)  # look the same way
            self.view = CandidateView(here, self.ctx.cfg.mast.clamp(turn, tilt, lift),
                                      method=self.view.method)
            self._start_point()
            return
        gone = math.hypot(part[0] - here[0], part[1] - here[1])
        self.stays.append(f"step {self.step}: part way, {gone:.2f} m toward a station "
                          f"{math.hypot(there[0] - here[0], there[1] - here[1]):.2f} m away: {reason}")
        turn = math.remainder(pan + there[2] - part[2], math.tau)
        self.view = CandidateView(part, self.ctx.cfg.mast.clamp(turn, tilt, lift),
                                  method=self.view.method)
        self._goto(MissionPhase.MOVE)
        self._request(kind="goto", target=part)

    def _look_at_swept(self, here: Pose3, there: Pose3, pts: NDArray[np.float64]) -> bool:
        """Make the step's next view a look at the unknown ground the move to ``there`` would
        sweep (``pts``; its cells nearest the rover), if the look budget allows: the first look
        for a station, then more while the last one mapped some of it. True if it is now that
        look."""
        assert self.view is not None
        if len(pts) == 0:
            return False
        if self._looked != there:
            self._looked, self._look_n, self._look_left = there, 0, len(pts)
        elif self._look_n >= self.ctx.cfg.mission.max_looks_per_move or len(pts) >= self._look_left:
            return False  # out of looks, or the last look mapped none of it (textureless, hidden)
        self._look_n += 1
        self._look_left = len(pts)
        d = np.hypot(pts[:, 0] - here[0], pts[:, 1] - here[1])
        near = pts[d <= d.min() + LOOK_DEPTH_M]
        self.looks += 1
        self.event("LOOK", n=len(near), x=there[0], y=there[1])
        self.pending.insert(0, self.view)
        self.view = CandidateView(here, look_joints(here, near, self.ctx.cfg.mast), method="look")
        self._start_point()
        return True

    def _part_way_steps(self, here: Pose3, there: Pose3) -> Generator[None, None, Pose3 | None]:
        """The allowed pose nearest ``there`` among the points every ``PART_STEP_M`` along the
        planned drive (its heading kept, no final turn) and along the rover's own heading
        (straight ahead or behind, no turn at all), at least ``MIN_MOVE_M`` from here and
        ``MIN_MOVE_M`` nearer the station; None if there is none."""
        dist = math.hypot(there[0] - here[0], there[1] - here[1])
        ux, uy = (there[0] - here[0]) / max(dist, 1e-9), (there[1] - here[1]) / max(dist, 1e-9)
        heading = goto_legs(here, there)[1][2]
        c, s = math.cos(here[2]), math.sin(here[2])
        ahead = (there[0] - here[0]) * c + (there[1] - here[1]) * s  # the station along the heading
        cands: list[Pose3] = []
        for t in np.arange(PART_STEP_M, dist - PART_STEP_M / 2, PART_STEP_M):
            cands.append((here[0] + t * ux, here[1] + t * uy, heading))
        for t in np.arange(PART_STEP_M, abs(ahead) + PART_STEP_M / 2, PART_STEP_M):
            t = math.copysign(min(t, abs(ahead)), ahead)
            cands.append((here[0] + t * c, here[1] + t * s, here[2]))
        gap = [math.hypot(there[0] - p[0], there[1] - p[1]) for p in cands]
        for k in np.argsort(gap, kind="stable"):
            p = cands[int(k)]
            if gap[k] > dist - MIN_MOVE_M:
                break
            if math.hypot(p[0] - here[0], p[1] - here[1]) >= MIN_MOVE_M:
                if self.geofence.check(here, p).allowed:
                    return p
                yield  # one check a slice
        return None

    def _look_around(self) -> bool:
        """If the geofence would not let the rover stay where it stands (the fitted edge runs
        within the margin of its wheels, often across unmapped ground beside it), make this
        step a look at the unknown ground nearest the edge within ``setback_m``; once per
        pose. True if the step's view is now that look. In the foreground (one fence set-up
        and one check of a standing rover, a few ms once a step): the next-view request then
        goes out in the frame the step's map arrived, also in a mission resumed there."""
        if self.nav is None:
            return False
        here = (self.nav.x, self.nav.y, self.nav.yaw)
        if self._looked_from == here or self.edge is None:
            return False
        self._fence(here)
        if self.geofence.check(here, here, known_ground=False).allowed:
            return False
        # Target: the unknown ground between the rover and the fitted edge, around the edge
        # point nearest the rover, out to setback_m past it on the drop side.
        setback = self.ctx.cfg.edge.setback_m
        q = shapely.get_coordinates(shapely.shortest_line(shapely.Point(here[:2]), self.edge.lines))[-1]
        pts = self.geofence.known.unknown_points(shapely.Point(q).buffer(setback))
        if len(pts) == 0:
            return False
        self._looked_from = here
        self.looks += 1
        self.event("LOOK", n=len(pts), x=here[0], y=here[1])
        self.view = CandidateView(here, look_joints(here, pts, self.ctx.cfg.mast), method="look")
        return True

    def _ground_z(self) -> float:
        """The ground under the rover, map datum (the pose chain's body height)."""
        return 0.0 if self.nav is None else float(self.nav.z_m)

    def _fence(self, here: Pose3) -> None:
        """The geofence on the latest edge fit and map, and the ground the rover stands on."""
        fence_on(self.geofence, self.latest, self.edge, here)
        yaw_var = math.nan if self.nav is None else float(self.nav.cov[2, 2])
        self.geofence.set_drift(math.sqrt(yaw_var) if yaw_var >= 0.0 else math.nan, self.ctx.cfg.motion)

    def _planner_state(self) -> PlannerState:
        assert self.nav is not None and self.latest is not None
        cfg = self.ctx.cfg
        path = (
            edge_path(self.edge, cfg.edge.setback_m, cfg.edge.path_spacing_m, cfg.geofence.extend_m)
            if self.edge is not None
            else np.zeros((0, 3))
        )
        self._fence((self.nav.x, self.nav.y, self.nav.yaw))
        sigma = float(np.sqrt(max(0.0, (self.nav.cov[0, 0] + self.nav.cov[1, 1]) / 2)))
        return PlannerState(
            map=self.latest.snapshot,
            rover=(self.nav.x, self.nav.y, self.nav.yaw),
            joints=self.nav.joints,
            path=path,
            motion_ok=lambda a, b: self.geofence.check(a, b, known_ground=False).allowed,
            edge_xy=None if self.edge is None else self.edge.points_xy,
            ground_z_m=self._ground_z(),  # the ground under the rover (on a slope, not the start's)
            sigma_loc_m=sigma,
        )


def fence_on(fence: Geofence, latest: MapUpdate | None, edge: EdgeModel | None, here: Pose3) -> None:
    """Set ``fence`` on a map update (known ground, drop cells), an edge fit and the pose the
    rover stands at (the mission's check; ``hil_sim.ground_watch`` builds its own the same way)."""
    if latest is not None:
        fence.set_map(latest.snapshot.grid, latest.snapshot.n)
        if latest.drop is not None:
            fence.set_drop(latest.snapshot.grid, latest.drop)
    fence.set_edge(edge, here)
