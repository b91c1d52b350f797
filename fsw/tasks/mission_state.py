"""The mission's phases and its checkpointed state (paper Figure 4; docs/algorithm.md §2-§4).

After each imaging step the sequencer (``fsw.tasks.mission``) writes ONE checkpoint holding
the map of that step and everything needed to continue from it: the step and phase, the
step records, the pose estimate and its covariance, the edge model (§2), the last map update
(mapped cells, the region-of-interest fraction of §3.6), the counters, each task's own
state (the ``checkpoint_state``/``restore_state`` methods of the tasks that have them:
odometry, planner, view counts) and the sections that resources registered as ``checkpoint_hooks`` (the HIL
bench's truth and random generators, so a lockstep resume continues the same run). The
interest function (§3.4) is a map layer and travels with the map.

The mission's own section is typed (:class:`MissionSection`, the last map update in it a
:class:`LatestSection`), each with an explicit JSON form read back field by field
(``fsw.tasks.state_json``). The format is version ``SCHEMA``; fields added since version 1 was
first written are optional with the value an older mission had, so older checkpoints resume.
Everything is plain JSON: floats round-trip exactly (``repr``), shapely geometries go as WKB
hex. ``StateError`` names what is wrong with a state that cannot be used; the sequencer turns
it into an event, never a traceback.
"""

from __future__ import annotations

import base64
import binascii
import enum
import hashlib
import json
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from typing import Any, Protocol

import numpy as np
import shapely
import shapely.errors
from numpy.typing import NDArray
from shapely.geometry import MultiLineString, MultiPolygon, Polygon

from fsw.core.edge.edge import EdgeModel
from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap
from fsw.settings import FswConfig
from fsw.tasks.base import FlightContext
from fsw.tasks.messages import MapUpdate, NavPose
from fsw.tasks.state_json import (
    JsonObject,
    StateError,
    as_float,
    as_int,
    as_object,
    as_str,
    floats,
    get_float,
    get_int,
    get_list,
    get_opt_object,
    get_opt_str,
    get_str,
    matrix,
    pose3,
)

SCHEMA = 1
# The untyped section of a task that reads its own fields (the perception task's); typed
# sections use ``JsonObject`` and ``fsw.tasks.state_json``.
JsonDict = dict[str, Any]  # type: ignore[explicit-any]
Pose3 = tuple[float, float, float]

__all__ = ["SCHEMA", "JsonDict", "JsonObject", "MissionPhase", "StateError", "StepRecord"]


class MissionPhase(enum.StrEnum):
    """The sequencer's states; a ``str`` so telemetry and summaries keep their text."""

    IDLE = "IDLE"
    INIT = "INIT"
    SELECT = "SELECT"
    MOVE = "MOVE"
    POINT = "POINT"
    ACQUIRE = "ACQUIRE"
    TRANSMIT = "TRANSMIT"
    DONE = "DONE"
    SAFE = "SAFE"


STATES = tuple(p.value for p in MissionPhase)


@dataclass
class StepRecord:
    """One imaging step of the run summary (docs/experiments.md, summary.json)."""

    step: int
    mapped_cells: int
    expected_new_cells: float
    obtained_new_cells: int
    pose: dict[str, float]
    # Host seconds from the mission task's start to the step's view, as this run of the flight
    # software measured them (the summary's wall-clock field); None for a step restored from a
    # checkpoint, which keeps no wall-clock time: a lockstep run writes the same checkpoints,
    # byte for byte, every time.
    wall_s: float | None
    sim_s: float
    # how the step's view came: the planner's method (rated: expected_new_cells is its prediction),
    # "look" (unknown ground a move would cross), "part-way" or "stay" (a refused move; the
    # rated view's pose was not reached, so its prediction does not apply), "panorama"
    view: str = ""
    view_new_cells: int = -1  # new cells of the step's last view alone (-1: not recorded)


def fingerprint(cfg: FswConfig) -> str:
    """What a resumed mission must share with the one that wrote the checkpoint: the map grid,
    the fusion cap and the mapping method (a different one would continue someone else's plan)."""
    g = MapGrid.from_config(cfg.map)
    key = {
        "grid": [g.x0, g.y0, g.cell, g.nx, g.ny],
        "n_max": cfg.fusion.n_max,
        "method": cfg.mission.method,
    }
    return hashlib.sha256(json.dumps(key, sort_keys=True, default=repr).encode()).hexdigest()[:16]


# -- pieces -------------------------------------------------------------------------------------
def edge_to_json(edge: EdgeModel | None) -> JsonObject | None:
    if edge is None:
        return None
    return {
        "method": edge.method,
        "points_xy": np.asarray(edge.points_xy, float).reshape(-1, 2).tolist(),
        "lines": shapely.to_wkb(edge.lines, hex=True),
        "safe_polygon": None if edge.safe_polygon is None else shapely.to_wkb(edge.safe_polygon, hex=True),
    }


def edge_from_json(d: JsonObject | None) -> EdgeModel | None:
    if d is None:
        return None
    try:
        lines = shapely.from_wkb(get_str(d, "lines"))
        poly = None if d.get("safe_polygon") is None else shapely.from_wkb(get_str(d, "safe_polygon"))
    except shapely.errors.ShapelyError as exc:
        raise StateError(f"edge model geometry unreadable ({exc})") from None
    if not isinstance(lines, MultiLineString) or not (poly is None or isinstance(poly, Polygon | MultiPolygon)):
        raise StateError("edge model geometry of the wrong type")
    pts = np.asarray([floats(r, "edge.points_xy", 2) for r in get_list(d, "points_xy")],
                     dtype=np.float64).reshape(-1, 2)
    return EdgeModel(get_str(d, "method"), pts, lines, poly)


def nav_to_json(nav: NavPose | None) -> JsonObject | None:
    if nav is None:
        return None
    return {
        "time_s": nav.time_s, "x": nav.x, "y": nav.y, "yaw": nav.yaw,
        "cov": np.asarray(nav.cov, float).tolist(), "joints": list(nav.joints), "moving": nav.moving,
        "roll": nav.roll, "pitch": nav.pitch, "z_m": nav.z_m, "attitude_valid": nav.attitude_valid,
        "att_cov": None if nav.att_cov is None else np.asarray(nav.att_cov, float).tolist(),
    }


def nav_from_json(d: JsonObject | None) -> NavPose | None:
    if d is None:
        return None
    try:
        cov = np.asarray(matrix(d.get("cov"), "nav.cov", 3, 3), dtype=np.float64)
        joints = pose3(d.get("joints"), "nav.joints")
    except StateError:
        raise StateError("pose estimate of the wrong shape") from None
    att = d.get("att_cov")  # the attitude fields: absent from checkpoints before them (level, z = 0)
    try:
        att_cov = None if att is None else np.asarray(matrix(att, "nav.att_cov", 3, 3), dtype=np.float64)
    except StateError:
        raise StateError("attitude covariance of the wrong shape") from None
    moving, valid = d.get("moving"), d.get("attitude_valid", False)
    if not isinstance(moving, bool) or not isinstance(valid, bool):
        raise StateError("nav: moving/attitude_valid not true/false")
    return NavPose(get_float(d, "time_s"), get_float(d, "x"), get_float(d, "y"), get_float(d, "yaw"), cov,
                   joints, moving,
                   roll=get_float(d, "roll", 0.0), pitch=get_float(d, "pitch", 0.0),
                   z_m=get_float(d, "z_m", 0.0), att_cov=att_cov, attitude_valid=valid)


def records_to_json(records: list[StepRecord]) -> list[JsonObject]:
    """Each record, without its wall-clock time (``StepRecord.wall_s``: what the host took is
    no part of the mission's state); ``view`` and ``view_new_cells`` only when set, so a
    checkpoint written before they existed reads back and writes out unchanged."""
    out = []
    for r in records:
        d = asdict(r)
        del d["wall_s"]
        if r.view == "":
            del d["view"]
        if r.view_new_cells == -1:
            del d["view_new_cells"]
        out.append(d)
    return out


def records_from_json(rows: list[object]) -> list[StepRecord]:
    out = []
    for row in rows:
        r = as_object(row, "records[]")
        step, cells, expected = get_int(r, "step"), get_int(r, "mapped_cells"), get_float(r, "expected_new_cells")
        obtained = get_int(r, "obtained_new_cells")
        pose = {str(k): as_float(v, "records[].pose") for k, v in as_object(r.get("pose"), "records[].pose").items()}
        out.append(StepRecord(step, cells, expected, obtained, pose, None, get_float(r, "sim_s"),
                              get_str(r, "view", ""), get_int(r, "view_new_cells", -1)))
    return out


def mask_to_json(mask: NDArray[np.bool_] | None) -> JsonObject | None:
    """A boolean map mask (the drop cells of ``MapUpdate.drop``) as packed bits."""
    if mask is None:
        return None
    m = np.asarray(mask, dtype=bool)
    return {"shape": list(m.shape), "bits": base64.b64encode(np.packbits(m).tobytes()).decode("ascii")}


def mask_from_json(d: JsonObject | None, shape: tuple[int, int]) -> NDArray[np.bool_] | None:
    if d is None:
        return None
    got = tuple(as_int(v, "mask.shape") for v in get_list(d, "shape"))
    if got != shape:
        raise StateError(f"mask of shape {got}, the map is {shape}")
    try:
        bits = np.frombuffer(base64.b64decode(get_str(d, "bits"), validate=True), dtype=np.uint8)
    except binascii.Error as exc:
        raise StateError(f"mask not base64 ({exc})") from None
    n = shape[0] * shape[1]
    if bits.size != (n + 7) // 8:
        raise StateError("mask of the wrong size")
    return np.unpackbits(bits)[:n].reshape(shape).astype(bool)


# -- the mission's section ------------------------------------------------------------------------
@dataclass(frozen=True)
class LatestSection:
    """The last map update of a checkpoint (its map is the checkpoint's own)."""

    view_id: int
    time_s: float
    mapped_cells: int
    new_cells: int
    points: int
    misses: int
    expected_new_cells: float
    edge: EdgeModel | None
    outliers: int
    edge_points: int
    roi_mapped_fraction: float
    drop: NDArray[np.bool_] | None

    @classmethod
    def of(cls, up: MapUpdate) -> LatestSection:
        return cls(up.view_id, up.time_s, up.mapped_cells, up.new_cells, up.points, up.misses,
                   up.expected_new_cells, up.edge, up.outliers, up.edge_points, up.roi_mapped_fraction, up.drop)

    def update(self, emap: ElevationMap) -> MapUpdate:
        """The map update again, on the checkpoint's map ``emap``."""
        return MapUpdate(self.view_id, self.time_s, self.mapped_cells, self.new_cells, self.points, self.misses,
                         self.expected_new_cells, emap, self.edge, self.outliers, self.edge_points,
                         self.roi_mapped_fraction, drop=self.drop)

    def to_json(self) -> JsonObject:
        return {
            "view_id": self.view_id, "time_s": self.time_s, "mapped_cells": self.mapped_cells,
            "new_cells": self.new_cells, "points": self.points, "misses": self.misses,
            "expected_new_cells": self.expected_new_cells, "edge": edge_to_json(self.edge),
            "extra": {"outliers": self.outliers, "edge_points": self.edge_points,
                      "roi_mapped_fraction": self.roi_mapped_fraction},
            "drop": mask_to_json(self.drop),
        }

    @classmethod
    def from_json(cls, d: JsonObject, shape: tuple[int, int]) -> LatestSection:
        extra = as_object(d.get("extra", {}), "latest.extra")
        return cls(get_int(d, "view_id"), get_float(d, "time_s"), get_int(d, "mapped_cells"),
                   get_int(d, "new_cells"), get_int(d, "points"), get_int(d, "misses"),
                   get_float(d, "expected_new_cells"), edge_from_json(get_opt_object(d, "edge")),
                   get_int(extra, "outliers", 0), get_int(extra, "edge_points", 0),
                   get_float(extra, "roi_mapped_fraction", 0.0), mask_from_json(get_opt_object(d, "drop"), shape))


def _opt_pose(d: JsonObject, key: str) -> Pose3 | None:
    v = d.get(key)
    return None if v is None else pose3(v, key)


@dataclass
class MissionSection:
    """The sequencer's own checkpoint section (``state["mission"]``)."""

    phase: MissionPhase
    step: int
    records: list[StepRecord]
    request_id: int
    edge_violations: int
    safe_entries: int
    end: str | None
    safe_reason: str | None
    edge: EdgeModel | None
    nav: NavPose | None
    latest: LatestSection | None
    looks: int = 0
    stays: list[str] = field(default_factory=list)
    looked: Pose3 | None = None  # the station the last looks were for
    looked_from: Pose3 | None = None
    look_n: int = 0
    look_left: int = 0
    stood_on: list[str] = field(default_factory=list)  # the ground stood on, as WKB hex

    def to_json(self) -> JsonObject:
        return {
            "phase": str(self.phase), "step": self.step, "records": records_to_json(self.records),
            "request_id": self.request_id, "edge_violations": self.edge_violations,
            "safe_entries": self.safe_entries, "end": self.end, "safe_reason": self.safe_reason,
            "edge": edge_to_json(self.edge), "nav": nav_to_json(self.nav),
            "latest": None if self.latest is None else self.latest.to_json(),
            "looks": self.looks, "stays": list(self.stays),
            "looked": None if self.looked is None else list(self.looked),
            "looked_from": None if self.looked_from is None else list(self.looked_from),
            "look_n": self.look_n, "look_left": self.look_left, "stood_on": list(self.stood_on),
        }

    @classmethod
    def from_json(cls, d: JsonObject, shape: tuple[int, int]) -> MissionSection:
        """The section, validated (``StateError`` naming the field if it cannot be used);
        ``shape`` is the checkpoint map's, for the masks."""
        try:
            phase = MissionPhase(get_str(d, "phase"))
        except ValueError:
            raise StateError(f"phase: unknown ({d.get('phase')!r})") from None
        latest = get_opt_object(d, "latest")
        return cls(
            phase=phase, step=get_int(d, "step"), records=records_from_json(get_list(d, "records")),
            request_id=get_int(d, "request_id"), edge_violations=get_int(d, "edge_violations"),
            safe_entries=get_int(d, "safe_entries"), end=get_opt_str(d, "end"),
            safe_reason=get_opt_str(d, "safe_reason"), edge=edge_from_json(get_opt_object(d, "edge")),
            nav=nav_from_json(get_opt_object(d, "nav")),
            latest=None if latest is None else LatestSection.from_json(latest, shape),
            looks=get_int(d, "looks", 0), stays=[as_str(x, "stays[]") for x in get_list(d, "stays", [])],
            looked=_opt_pose(d, "looked"), looked_from=_opt_pose(d, "looked_from"),
            look_n=get_int(d, "look_n", 0), look_left=get_int(d, "look_left", 0),
            stood_on=[as_str(x, "stood_on[]") for x in get_list(d, "stood_on", [])],
        )


# -- the other tasks and the hooks ----------------------------------------------------------------
class Checkpointed(Protocol):
    """A task with a section of its own in the checkpoint."""

    @property
    def name(self) -> str: ...

    @property
    def ctx(self) -> FlightContext: ...

    def restore_state(self, st: JsonObject) -> None: ...


def collect_task_states(tasks: Mapping[str, object]) -> JsonObject:
    """Each task's ``checkpoint_state()`` (tasks without one keep nothing)."""
    out: JsonObject = {}
    for name, task in tasks.items():
        fn = getattr(task, "checkpoint_state", None)
        if callable(fn):
            out[name] = fn()
    return out


def collect_hooks(hooks: Mapping[str, Callable[[], object]] | None) -> JsonObject:
    """The sections of ``checkpoint_hooks`` resources (callables returning JSON-able dicts)."""
    return {name: fn() for name, fn in (hooks or {}).items()}


def check_schema(state: Mapping[str, object], fp: str) -> JsonObject:
    """The mission section of a checkpoint state, or ``StateError`` saying why not."""
    if state.get("schema") != SCHEMA:
        raise StateError(f"mission state schema {state.get('schema')!r} (this build reads {SCHEMA})")
    if state.get("fingerprint") != fp:
        raise StateError("checkpoint was written with a different map grid, fusion cap or method")
    mission = state.get("mission")
    if not isinstance(mission, dict):
        raise StateError("no mission section")
    return as_object(mission, "mission")


def restored_section(ctx: FlightContext, name: str) -> JsonObject | None:
    """Task ``name``'s section of the start-up checkpoint, if there is a compatible one.

    Tasks call this from ``setup`` (the store loads once, ``MapStore.restore``); the mission
    sequencer reports an incompatible or malformed state as an event."""
    store = ctx.res.map_store
    if store is None:
        return None
    state = store.restore().state
    if not state or state.get("schema") != SCHEMA or state.get("fingerprint") != fingerprint(ctx.cfg):
        return None
    tasks = state.get("tasks")
    sec = tasks.get(name) if isinstance(tasks, dict) else None
    return as_object(sec, name) if isinstance(sec, dict) else None


def restore_into(task: Checkpointed) -> bool:
    """Restore ``task`` from its section of the start-up checkpoint, if any. A section the task
    cannot use leaves the task fresh and is recorded on the load result (``errors``); the
    sequencer then refuses the resume with an event naming it."""
    sec = restored_section(task.ctx, task.name)
    store = task.ctx.res.map_store
    if sec is None or store is None:
        return False
    try:
        task.restore_state(sec)
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        store.restore().errors.append(f"{task.name}: {type(exc).__name__}: {exc}")
        return False
    return True
