"""The mission's phases and its checkpointed state (paper Figure 4; docs/algorithm.md §2-§4).

After each imaging step the sequencer (``fsw.tasks.mission``) writes ONE checkpoint holding
the map of that step and everything needed to continue from it: the step and phase, the
step records, the pose estimate and its covariance, the edge model (§2), the last map update
(mapped cells, the region-of-interest fraction of §3.6), the counters, each task's own
state (the ``checkpoint_state``/``restore_state`` methods of the tasks that have them:
odometry, planner, view counts) and the sections that resources registered as ``checkpoint_hooks`` (the HIL
bench's truth and random generators, so a lockstep resume continues the same run). The
interest function (§3.4) is a map layer and travels with the map.

Everything here is plain JSON: floats round-trip exactly (``repr``), shapely geometries go
as WKB hex. ``StateError`` names what is wrong with a state that cannot be used; the
sequencer turns it into an event, never a traceback.
"""

from __future__ import annotations

import base64
import binascii
import enum
import hashlib
import json
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import shapely
import shapely.errors
from numpy.typing import NDArray
from shapely.geometry import MultiLineString, MultiPolygon, Polygon

from fsw.core.edge.edge import EdgeModel
from fsw.core.geometry import MapGrid
from fsw.tasks.messages import NavPose

SCHEMA = 1
JsonDict = dict[str, Any]  # a checkpoint section: a JSON object (the tasks' sections use this name)


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


class StateError(ValueError):
    """A checkpointed mission state that cannot be resumed (malformed or incompatible)."""


@dataclass
class StepRecord:
    """One imaging step of the run summary (docs/experiments.md, summary.json)."""

    step: int
    mapped_cells: int
    expected_new_cells: float
    obtained_new_cells: int
    pose: dict[str, float]
    wall_s: float
    sim_s: float


def fingerprint(cfg: Any) -> str:
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
def edge_to_json(edge: EdgeModel | None) -> dict[str, Any] | None:
    if edge is None:
        return None
    return {
        "method": edge.method,
        "points_xy": np.asarray(edge.points_xy, float).reshape(-1, 2).tolist(),
        "lines": shapely.to_wkb(edge.lines, hex=True),
        "safe_polygon": None if edge.safe_polygon is None else shapely.to_wkb(edge.safe_polygon, hex=True),
    }


def edge_from_json(d: dict[str, Any] | None) -> EdgeModel | None:
    if d is None:
        return None
    try:
        lines = shapely.from_wkb(d["lines"])
        poly = None if d["safe_polygon"] is None else shapely.from_wkb(d["safe_polygon"])
    except shapely.errors.ShapelyError as exc:
        raise StateError(f"edge model geometry unreadable ({exc})") from None
    if not isinstance(lines, MultiLineString) or not (poly is None or isinstance(poly, Polygon | MultiPolygon)):
        raise StateError("edge model geometry of the wrong type")
    pts = np.asarray(d["points_xy"], dtype=np.float64).reshape(-1, 2)
    return EdgeModel(str(d["method"]), pts, lines, poly)


def nav_to_json(nav: NavPose | None) -> dict[str, Any] | None:
    if nav is None:
        return None
    return {
        "time_s": nav.time_s, "x": nav.x, "y": nav.y, "yaw": nav.yaw,
        "cov": np.asarray(nav.cov, float).tolist(), "joints": list(nav.joints), "moving": nav.moving,
        "roll": nav.roll, "pitch": nav.pitch, "z_m": nav.z_m, "attitude_valid": nav.attitude_valid,
        "att_cov": None if nav.att_cov is None else np.asarray(nav.att_cov, float).tolist(),
    }


def nav_from_json(d: dict[str, Any] | None) -> NavPose | None:
    if d is None:
        return None
    cov = np.asarray(d["cov"], dtype=np.float64)
    joints = tuple(float(j) for j in d["joints"])
    if cov.shape != (3, 3) or len(joints) != 3:
        raise StateError("pose estimate of the wrong shape")
    att = d.get("att_cov")  # the attitude fields: absent from checkpoints before them (level, z = 0)
    att_cov = None if att is None else np.asarray(att, dtype=np.float64)
    if att_cov is not None and att_cov.shape != (3, 3):
        raise StateError("attitude covariance of the wrong shape")
    return NavPose(float(d["time_s"]), float(d["x"]), float(d["y"]), float(d["yaw"]), cov,
                   (joints[0], joints[1], joints[2]), bool(d["moving"]),
                   roll=float(d.get("roll", 0.0)), pitch=float(d.get("pitch", 0.0)),
                   z_m=float(d.get("z_m", 0.0)), att_cov=att_cov,
                   attitude_valid=bool(d.get("attitude_valid", False)))


def records_to_json(records: list[StepRecord]) -> list[dict[str, Any]]:
    return [asdict(r) for r in records]


def records_from_json(rows: list[dict[str, Any]]) -> list[StepRecord]:
    return [StepRecord(**r) for r in rows]


# -- the other tasks and the hooks ----------------------------------------------------------------
def collect_task_states(tasks: dict[str, Any]) -> dict[str, Any]:
    """Each task's ``checkpoint_state()`` (tasks without one keep nothing)."""
    out: dict[str, Any] = {}
    for name, task in tasks.items():
        fn = getattr(task, "checkpoint_state", None)
        if callable(fn):
            out[name] = fn()
    return out


def collect_hooks(hooks: dict[str, Any] | None) -> dict[str, Any]:
    """The sections of ``checkpoint_hooks`` resources (callables returning JSON-able dicts)."""
    return {name: fn() for name, fn in (hooks or {}).items()}


def check_schema(state: dict[str, Any], fp: str) -> dict[str, Any]:
    """The mission section of a checkpoint state, or ``StateError`` saying why not."""
    if state.get("schema") != SCHEMA:
        raise StateError(f"mission state schema {state.get('schema')!r} (this build reads {SCHEMA})")
    if state.get("fingerprint") != fp:
        raise StateError("checkpoint was written with a different map grid, fusion cap or method")
    mission = state.get("mission")
    if not isinstance(mission, dict):
        raise StateError("no mission section")
    return mission


def restored_section(ctx: Any, name: str) -> dict[str, Any] | None:
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
    return sec if isinstance(sec, dict) else None


def restore_into(task: Any) -> bool:
    """Restore ``task`` from its section of the start-up checkpoint, if any. A section the task
    cannot use leaves the task fresh and is recorded on the load result (``errors``); the
    sequencer then refuses the resume with an event naming it."""
    sec = restored_section(task.ctx, task.name)
    if sec is None:
        return False
    try:
        task.restore_state(sec)
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        task.ctx.res.map_store.restore().errors.append(f"{task.name}: {type(exc).__name__}: {exc}")
        return False
    return True


def mask_to_json(mask: NDArray[np.bool_] | None) -> dict[str, Any] | None:
    """A boolean map mask (the drop cells of ``MapUpdate.drop``) as packed bits."""
    if mask is None:
        return None
    m = np.asarray(mask, dtype=bool)
    return {"shape": list(m.shape), "bits": base64.b64encode(np.packbits(m).tobytes()).decode("ascii")}


def mask_from_json(d: dict[str, Any] | None, shape: tuple[int, int]) -> NDArray[np.bool_] | None:
    if d is None:
        return None
    if tuple(d["shape"]) != shape:
        raise StateError(f"mask of shape {tuple(d['shape'])}, the map is {shape}")
    try:
        bits = np.frombuffer(base64.b64decode(d["bits"], validate=True), dtype=np.uint8)
    except binascii.Error as exc:
        raise StateError(f"mask not base64 ({exc})") from None
    n = shape[0] * shape[1]
    if bits.size != (n + 7) // 8:
        raise StateError("mask of the wrong size")
    return np.unpackbits(bits)[:n].reshape(shape).astype(bool)

