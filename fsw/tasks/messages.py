"""Messages on the software bus between the mission tasks (topic names and payloads).

The sensing cycle (docs/architecture.md): ``mission`` asks ``camera`` for a view, the
pair goes to ``perception`` which fuses it into the map and re-fits the edge, ``nbv``
rates candidate views on a snapshot of the map, ``motion`` moves the wheels and the mast.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray
from shapely.geometry.base import BaseGeometry

from fsw.comm.link_sender import SenderState
from fsw.core.edge.edge import EdgeModel
from fsw.core.geometry import CameraPose
from fsw.core.localization.nav_fix import NavFix
from fsw.core.map.elevation_map import ElevationMap
from fsw.core.registration.registration import RegistrationSummary
from fsw.core.stereo.rig_drift import RigAlignment

# Topic names (one place, so a typo is an import error, not a silent loss).
CAMERA_REQUEST = "camera.request"
CAMERA_FRAME = "camera.frame"
MAP_UPDATED = "map.updated"
NAV_POSE = "nav.pose"
NAV_FIX = "nav.fix"  # a registered view's correction of the rover pose (fsw.core.localization.nav_fix.NavFix)
NBV_REQUEST = "nbv.request"
NBV_RESULT = "nbv.result"
RADIO_SEND = "radio.send"
RADIO_FIX_REQUEST = "radio.fix_request"  # a FIX_REQUEST the radio received (fsw.comm.team.fix_packets.FixRequest)
RADIO_FIX_OUT = "radio.fix_out"  # an encoded FIX / NO_FIX the radio sends ahead of map bytes (bytes)
FIX_VIEW_BASE = 1 << 30  # view ids from here are the fixer's pairs of the Cliff-bot, not views of the map
RADIO_STATUS = "radio.status"
VIEW_FAILED = "view.failed"


@dataclass(frozen=True)
class NavPose:
    """The rover pose estimate (x, y, yaw) with its 3x3 covariance, and the mast joints; the
    body attitude (roll, pitch, rad), height ``z_m`` and their 3x3 covariance ``att_cov``
    (docs/algorithm.md §5.1; None: level at z = 0, as before the attitude sensor). ``fix_id``: the
    last navigation fix applied to the pose (``fsw.core.localization.nav_fix``; 0: none), ``fix_seen`` the
    last one received (applied or refused). ``cov`` is relative to the map the rover registers on;
    ``frame_cov`` against its start, the team's frame (``Odometry.frame_covariance``)."""

    time_s: float
    x: float
    y: float
    yaw: float
    cov: NDArray[np.float64]
    joints: tuple[float, float, float]  # pan, tilt (rad), lift (m)
    moving: bool = False
    roll: float = 0.0
    pitch: float = 0.0
    z_m: float = 0.0
    att_cov: NDArray[np.float64] | None = None  # (roll, pitch, z)
    attitude_valid: bool = False
    fix_id: int = 0
    fix_seen: int = 0
    frame_cov: NDArray[np.float64] | None = None  # (x, y, yaw) against the start, not the map (None: ``cov``)


@dataclass(frozen=True)
class CaptureRequest:
    """Ask for one stereo pair for view ``view_id`` (the planner's expected new cells ride along)."""

    view_id: int
    expected_new_cells: float = float("nan")


@dataclass(frozen=True)
class ViewFailed:
    """View ``view_id`` will not reach the map (no pair: camera timeout, dropout, broken link,
    no pose; or its stereo/merge job failed): the mission retries at once instead of waiting
    out its step timeout."""

    view_id: int
    reason: str


@dataclass(frozen=True)
class CameraFrame:
    """A stereo pair with the camera pose estimate at capture time (docs/algorithm.md §4)."""

    view_id: int
    time_s: float
    left: NDArray[np.uint8]
    right: NDArray[np.uint8]
    pose: CameraPose
    pose_cov: NDArray[np.float64]  # 6x6, rotation vector (rad) then translation (m)
    expected_new_cells: float = float("nan")
    ground_z_m: float = 0.0  # the ground under the rover at capture, map datum (``NavPose.z_m``)
    nav_fix_id: int = 0  # the navigation fix the pose holds (``NavPose.fix_id``)
    body_yaw_rad: float = float("nan")  # the rover's yaw at capture (``NavPose.yaw``; the mount biases need it)


@dataclass(frozen=True)
class MapUpdate:
    """What one merged view did to the map, and a snapshot for planning."""

    view_id: int
    time_s: float
    mapped_cells: int
    new_cells: int
    points: int
    misses: int
    expected_new_cells: float
    snapshot: ElevationMap  # a copy, safe to read while the map goes on
    edge: EdgeModel | None = None  # the polygon fit (Methods 4/5)
    outliers: int = 0  # points refused as outliers (§4)
    edge_points: int = 0  # edge cells found in this view
    roi_mapped_fraction: float = 0.0  # of the region of interest (the §3.6 end criterion)
    registration: RegistrationSummary | None = None  # the view's registration (§5.1, perception)
    view_cells: tuple[NDArray[np.int32], NDArray[np.float32]] | None = None  # flat cell index, mean height (m)
    camera_xyz: tuple[float, float, float] | None = None  # the (registered) camera centre
    drop: NDArray[np.bool_] | None = None  # mapped cells a step below the rover's ground (§2)
    nav_fix: NavFix | None = None  # the correction of the rover pose it found (also on ``nav.fix``)
    rig: RigAlignment | None = None  # the pair's rig-drift measurement (``fsw.core.stereo.rig_drift``)


# Motion (fsw/tasks/motion.py): requests from the sequencer, one status per request outcome.
MOTION_REQUEST = "motion.request"
MOTION_STATUS = "motion.status"
# The mission's ground (fsw/tasks/mission_ground.py): what its geofence stands on, after each change of
# its state, so a wheel move of another task (the fixer's turns in place) is checked the same way.
MISSION_GROUND = "mission.ground"


@dataclass(frozen=True)
class MissionGroundState:
    """The inputs of the mission's geofence besides the pose: its latest map update (known ground,
    drop cells), its edge fit (the last non-empty one) and the footprints the rover stood on."""

    latest: MapUpdate | None
    edge: EdgeModel | None
    stood_on: tuple[BaseGeometry, ...]


@dataclass(frozen=True)
class MotionRequest:
    """A move for the motion task. ``kind``: ``drive`` (``distance_m``, signed), ``turn``
    (``angle_rad``, CCW +), ``goto`` (``target`` = x, y, yaw in the odometry frame; yaw NaN:
    arrive with the travel heading), ``mast`` (``joints`` = pan, tilt rad, lift m), ``stop``,
    ``clear_faults`` (clear latched motor and mast faults; refused while the E-stop is engaged).
    ``speed`` (m/s or rad/s) 0 takes the configured default."""

    request_id: int
    kind: str
    distance_m: float = 0.0
    angle_rad: float = 0.0
    target: tuple[float, float, float] | None = None
    joints: tuple[float, float, float] | None = None
    speed: float = 0.0


class MoveOutcome(StrEnum):
    """How a motion request ended."""

    DONE = "done"
    ABORTED = "aborted"
    REFUSED = "refused"


@dataclass(frozen=True)
class MotionStatus:
    """Outcome of a :class:`MotionRequest`: ``done``, ``aborted`` or ``refused`` (with a reason)."""

    request_id: int
    kind: str
    state: MoveOutcome
    reason: str = ""
    time_s: float = 0.0


@dataclass(frozen=True)
class RadioSendRequest:
    """Ask the radio task to encode a map and send it as ``map_id``: ``snapshot``, or the
    latest ``map.updated`` one when None. A request for the map id already being encoded or
    sent is a repeat and changes nothing."""

    map_id: int
    snapshot: ElevationMap | None = None


@dataclass(frozen=True)
class RadioStatus:
    """The map link's sender state, published by the radio task whenever it changes."""

    state: SenderState
    time_s: float
    map_id: int = 0  # the map the state is about (0: none yet)

    @property
    def finished(self) -> bool:
        return self.state in (SenderState.DONE, SenderState.REJECTED, SenderState.FAILED)
