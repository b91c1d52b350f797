"""The mission's moves over unfamiliar ground and its planning inputs (docs/algorithm.md §2, §3;
issue 13 item 3): a part of :class:`fsw.tasks.mission.MissionTask`.

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
  one check a slice (``MissionGround.in_slack``); the mission's activations wait for it and then go on
  with its result. Done in the foreground it took 10-50 ms an activation (up to 590 ms for a
  part-way search on lab seed 2), 0.3-1.5 s on a flight computer 30x slower (issue 15).
- Another task's wheel move (the fixer's turns in place) is checked the same way
  (:func:`check_move`): on what the mission's geofence stands on, which the mission publishes on
  ``mission.ground`` at each change of its state (:meth:`MissionGround.shared`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Generator
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry.base import BaseGeometry

from fsw.core.edge.edge import EdgeModel, edge_path
from fsw.core.edge.geofence import Geofence, Verdict, goto_legs
from fsw.core.edge.look import look_joints
from fsw.core.planning.planners import PlannerState
from fsw.core.planning.view_candidates import CandidateView
from fsw.framework.jobs import Job, JobHandle
from fsw.settings import FswConfig
from fsw.tasks.messages import MapUpdate, MissionGroundState, NavPose

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


class GroundHost(Protocol):
    """What the ground-awareness needs of the mission sequencer: the step's inputs (read at the
    moment of use) and the three ways a step goes on."""

    @property
    def latest(self) -> MapUpdate | None: ...

    @property
    def edge(self) -> EdgeModel | None: ...

    @property
    def nav(self) -> NavPose | None: ...

    @property
    def step(self) -> int: ...

    @property
    def view(self) -> CandidateView | None: ...

    def event(self, name: str, **args: object) -> None: ...

    def submit_job(self, gen: Job, name: str) -> JobHandle: ...

    def enter_safe(self, reason: str) -> None: ...

    def drive(self, target: Pose3, view: CandidateView) -> None:
        """Drive to ``target``, then take ``view`` (its station is ``target``)."""

    def point(self, view: CandidateView) -> None:
        """Take ``view`` from where the rover stands (mast move, then the pair)."""

    def look_first(self, look: CandidateView) -> None:
        """Take ``look`` now, the step's view after it."""


class MissionGround:
    """The geofence of the mission, its slack job, the looks and the stays (module docstring).
    It acts on the sequencer only through :class:`GroundHost`."""

    def __init__(self, cfg: FswConfig, host: GroundHost) -> None:
        self.cfg = cfg
        self.host = host
        self.geofence = Geofence(cfg.geofence, cfg.rover)
        self.fence_job: FenceJob | None = None  # geofence work of a move, as a slack job
        self.looks = 0  # views of unknown ground before a move
        self.stays: list[str] = []  # why a step's view was taken without its move
        self.edge_violations = 0  # moves refused by the geofence (a look is not one)
        self.looked: Pose3 | None = None  # the station the last looks were for
        self.look_n = 0  # looks taken for it
        self.look_left = 0  # its unknown swept cells at the last look
        self.looked_from: Pose3 | None = None  # the pose the last look-around was taken from

    def stood_on_wkb(self) -> list[str]:
        """The ground the rover stood on (known ground of the geofence), as WKB hex (a checkpoint)."""
        return [str(shapely.to_wkb(g, hex=True)) for g in self.geofence.stood.footprints]

    def set_stood_on(self, stood: list[BaseGeometry]) -> None:
        self.geofence.stood.replace(stood)

    # -- the geofence work of a move, as a slack job ----------------------------------------------
    def in_slack(self, work: Generator[None, None, object], then: Callable[[JobHandle], None]) -> None:
        """Run geofence ``work`` as a slack job; ``then(job)`` in the mission's first
        activation after it ends, ``job.result`` its result (the module docstring)."""
        self.fence_job = FenceJob(self.host.submit_job(work, "geofence"), then)

    def job_pending(self) -> bool:
        """True while the mission waits for its geofence job; a finished one is taken up here
        (its continuation, or SAFE with the reason if the job failed)."""
        job = self.fence_job
        if job is None:
            return False
        if not job.handle.done:
            return True
        self.fence_job = None
        if job.handle.error is not None:
            self.host.enter_safe(f"geofence work failed: {type(job.handle.error).__name__}: {job.handle.error}")
        else:
            job.then(job.handle)
        return True

    def cancel_job(self) -> None:
        if self.fence_job is not None:
            self.fence_job.handle.cancel()
            self.fence_job = None

    # -- a move ------------------------------------------------------------------------------------
    def start_move(self, here: Pose3, there: Pose3) -> None:
        """Check the move from ``here`` to ``there`` in slack, then drive, look or stay."""
        self.in_slack(self._move_steps(here, there), lambda job: self._move_checked(here, there, job.result))

    def _move_steps(self, here: Pose3, there: Pose3) -> Generator[None, None, tuple[Verdict, NDArray[np.float64]]]:
        """The fence set up, the move checked and, if refused over unknown ground, that ground
        (one slice each)."""
        self.fence(here)
        yield
        verdict = self.geofence.check(here, there)
        if verdict.allowed or "unknown ground" not in verdict.reason:
            return verdict, np.zeros((0, 2))
        yield
        return verdict, self.geofence.unknown_points(here, there)

    def _move_checked(self, here: Pose3, there: Pose3, checked: tuple[Verdict, NDArray[np.float64]]) -> None:
        verdict, unknown = checked
        if verdict.allowed:
            view = self.host.view
            assert view is not None
            self.host.drive(there, view)
        else:
            self._refused(here, there, verdict.reason, unknown)

    def _refused(self, here: Pose3, there: Pose3, reason: str, unknown: NDArray[np.float64]) -> None:
        """The geofence refused the move: over unknown ground, look at it (see the module
        docstring); otherwise drive part of the way, as far as the geofence allows; otherwise
        take the step's view from here. Never a crossing, never a stall."""
        assert self.host.view is not None
        if "unknown ground" in reason and self._look_at_swept(here, there, unknown):
            return
        self.edge_violations += 1  # a refusal that stands (a look is not one)
        self.host.event("GEOFENCE", x=there[0], y=there[1], reason=reason)
        self.in_slack(self._part_way_steps(here, there),
                      lambda job: self._part_way_done(here, there, reason, job.result))

    def _part_way_done(self, here: Pose3, there: Pose3, reason: str, part: Pose3 | None) -> None:
        view = self.host.view
        assert view is not None
        pan, tilt, lift = view.joints
        if part is None:
            self.stays.append(f"step {self.host.step}: {reason}")
            turn = math.remainder(pan + there[2] - here[2], math.tau)  # look the same way
            self.host.point(CandidateView(here, self.cfg.mast.clamp(turn, tilt, lift), method="stay"))
            return
        gone = math.hypot(part[0] - here[0], part[1] - here[1])
        self.stays.append(f"step {self.host.step}: part way, {gone:.2f} m toward a station "
                          f"{math.hypot(there[0] - here[0], there[1] - here[1]):.2f} m away: {reason}")
        turn = math.remainder(pan + there[2] - part[2], math.tau)
        self.host.drive(part, CandidateView(part, self.cfg.mast.clamp(turn, tilt, lift), method="part-way"))

    def _look_at_swept(self, here: Pose3, there: Pose3, pts: NDArray[np.float64]) -> bool:
        """Make the step's next view a look at the unknown ground the move to ``there`` would
        sweep (``pts``; its cells nearest the rover), if the look budget allows: the first look
        for a station, then more while the last one mapped some of it. True if it is now that
        look."""
        if len(pts) == 0:
            return False
        if self.looked != there:
            self.looked, self.look_n, self.look_left = there, 0, len(pts)
        elif self.look_n >= self.cfg.mission.max_looks_per_move or len(pts) >= self.look_left:
            return False  # out of looks, or the last look mapped none of it (textureless, hidden)
        self.look_n += 1
        self.look_left = len(pts)
        d = np.hypot(pts[:, 0] - here[0], pts[:, 1] - here[1])
        near = pts[d <= d.min() + LOOK_DEPTH_M]
        self.looks += 1
        self.host.event("LOOK", n=len(near), x=there[0], y=there[1])
        self.host.look_first(CandidateView(here, look_joints(here, near, self.cfg.mast), method="look"))
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

    def look_around(self) -> CandidateView | None:
        """If the geofence would not let the rover stay where it stands (the fitted edge runs
        within the margin of its wheels, often across unmapped ground beside it), a look at the
        unknown ground nearest the edge within ``setback_m`` to make this step's view; once per
        pose. In the foreground (one fence set-up and one check of a standing rover, a few ms
        once a step): the next-view request then goes out in the frame the step's map arrived,
        also in a mission resumed there."""
        nav, edge = self.host.nav, self.host.edge
        if nav is None:
            return None
        here = (nav.x, nav.y, nav.yaw)
        if self.looked_from == here or edge is None:
            return None
        self.fence(here)
        if self.geofence.check(here, here, known_ground=False).allowed:
            return None
        # Target: the unknown ground between the rover and the fitted edge, around the edge
        # point nearest the rover, out to setback_m past it on the drop side.
        setback = self.cfg.edge.setback_m
        q = shapely.get_coordinates(shapely.shortest_line(shapely.Point(here[:2]), edge.lines))[-1]
        pts = self.geofence.known.unknown_points(shapely.Point(q).buffer(setback))
        if len(pts) == 0:
            return None
        self.looked_from = here
        self.looks += 1
        self.host.event("LOOK", n=len(pts), x=here[0], y=here[1])
        return CandidateView(here, look_joints(here, pts, self.cfg.mast), method="look")

    # -- the fence and the planner's inputs -----------------------------------------------------
    def fence(self, here: Pose3) -> None:
        """The geofence on the latest edge fit and map, and the ground the rover stands on."""
        set_fence(self.geofence, self.host.latest, self.host.edge, here, self.host.nav, self.cfg)

    def shared(self) -> MissionGroundState:
        """What the geofence stands on besides the pose (``mission.ground``: another task's wheel
        move is checked on it, :func:`check_move`)."""
        return MissionGroundState(self.host.latest, self.host.edge, tuple(self.geofence.stood.footprints))

    def planner_state(self) -> PlannerState:
        """The next-view request: the latest map, the pose, the edge path and the move check."""
        nav, latest, edge = self.host.nav, self.host.latest, self.host.edge
        assert nav is not None and latest is not None
        cfg = self.cfg
        path = (
            edge_path(edge, cfg.edge.setback_m, cfg.edge.path_spacing_m, cfg.geofence.extend_m)
            if edge is not None
            else np.zeros((0, 3))
        )
        self.fence((nav.x, nav.y, nav.yaw))
        sigma = float(np.sqrt(max(0.0, (nav.cov[0, 0] + nav.cov[1, 1]) / 2)))
        # not left the start: no footprint stood on half a station spacing or more from here
        at_start = self.geofence.known.stood_only_near(nav.x, nav.y, cfg.nbv.station_spacing_m / 2.0)
        return PlannerState(
            map=latest.snapshot,
            rover=(nav.x, nav.y, nav.yaw),
            joints=nav.joints,
            path=path,
            motion_ok=lambda a, b: self.geofence.check(a, b, known_ground=False).allowed,
            edge_xy=None if edge is None else edge.points_xy,
            ground_z_m=float(nav.z_m),  # the ground under the rover (on a slope, not the start's)
            sigma_loc_m=sigma,
            at_start=at_start,
        )


def set_fence(fence: Geofence, latest: MapUpdate | None, edge: EdgeModel | None, here: Pose3,
              nav: NavPose | None, cfg: FswConfig) -> None:
    """The mission's geofence set-up before a check: :func:`fence_on`, and the pose drift from the
    heading sigma of ``nav`` (none without a pose estimate)."""
    fence_on(fence, latest, edge, here)
    yaw_var = math.nan if nav is None else float(nav.cov[2, 2])
    fence.set_drift(math.sqrt(yaw_var) if yaw_var >= 0.0 else math.nan, cfg.motion)


def check_move(cfg: FswConfig, ground: MissionGroundState | None, nav: NavPose, there: Pose3
               ) -> Generator[None, None, Verdict]:
    """A wheel move of another task than the mission (the fixer's turns in place) from where the
    rover stands (``nav``) to ``there``, checked as the mission checks its own moves: a geofence
    set up the same way (:func:`set_fence`) on the mission's ground (``mission.ground``, its
    footprints stood on included) and :meth:`Geofence.check` (the swept wheel patches, the edge,
    known ground, the margin from unmapped ground). Refused while the mission has not shared its
    ground (no map: nothing is known). A slack job: the set-up, then the check."""
    if ground is None:
        return Verdict(False, "rejected: the mission's ground is not known (no map yet)", math.nan)
    fence = Geofence(cfg.geofence, cfg.rover)
    fence.stood.replace(ground.stood_on)
    here = (float(nav.x), float(nav.y), float(nav.yaw))
    set_fence(fence, ground.latest, ground.edge, here, nav, cfg)
    yield
    return fence.check(here, there)


def fence_on(fence: Geofence, latest: MapUpdate | None, edge: EdgeModel | None, here: Pose3) -> None:
    """Set ``fence`` on a map update (known ground, drop cells), an edge fit and the pose the
    rover stands at (the mission's check; ``hil_sim.mission.ground_watch`` builds its own the same way)."""
    if latest is not None:
        fence.set_map(latest.snapshot.grid, latest.snapshot.n)
        if latest.drop is not None:
            fence.set_drop(latest.snapshot.grid, latest.drop)
    fence.set_edge(edge, here)
