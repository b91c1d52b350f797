"""Why a truth overhang cell was not flagged: ``safer-hil experiment face-map --why``.

:class:`WhyScene` is the face-map experiment's scene (``hil_sim.team.face_scene.FaceScene``) that
also keeps each view's points in the face frame as they reach the face map (and those the
hand-over sent to the gravity grid). :func:`miss_reasons` then looks at every truth overhang cell
(``hil_sim.team.face_eval``: the normal through the cell's centre crosses the true surface more
than once, first and last crossing more than the gap apart) the face map did not flag, and
records what the views gave the detector there:

* ``unobservable``: no true sight line shows the cell as two surfaces
  (``face_eval.overhang_shown``);
* ``facing_far``: a view's true sight lines end in the cell on ground that faces the face
  (``face_eval.facing_seen``), the face map's facing test counted no point there, and the only
  views that showed that ground are the RECON-bot's, from the plateau metres away: a rock's side a
  few centimetres across under centimetres of depth noise along the sight line has no plane the
  view's points resolve (the fitted normal is uncertain by tens of degrees and the test's cone at
  ``facing_sigma`` refuses it; within that noise the fitted normal alone faces the face as often
  on a patch that does not);
* ``facing_unresolved``: as ``facing_far``, but a Cliff-bot view showed it too, and its stereo
  points did not resolve that ground's plane;
* ``no_inner``: no measured point lies near the inner surface (the first crossing, within half
  the gap) and no facing point or ray under it was counted;
* ``both_one_view``: one view has points near both surfaces in the cell (the within-view test's
  sub-cell or point count refused them);
* ``both_across``: the points near both surfaces come from different views only (the pooling:
  the across-view test's gate refused them);
* ``facing_few``, ``air_few``: the facing or the free-space test counted some evidence, below
  its threshold;
* ``neighbour_flagged``: a neighbouring cell is flagged (the flag lies a cell off: resolution);
* ``handed_over``: points near either surface in the cell's column went to the gravity grid
  only (the hand-over);
* ``spread``: the points in the cell, pooled over views, spread along the normal by more than
  the gap plus 3 sigma of their noise.

A missed cell may have several; ``primary`` is the first of the order above that holds.
:func:`false_flags` sorts the flags on single-surface cells (false flags) by the test that set
each (the face map's ``flagged_by``), the agent whose view did, and what the truth holds there,
the first of :data:`FALSE_CLASSES` that applies: ``part`` (an overhang covers part of the cell,
off its centre), ``wrong_surface`` (the map's height lies more than the gap off the true
surface), ``step`` (a true rise of the gap or more within 2 cells), ``other``. Per
scene, ``frame_off_deg`` (``face_eval.frame_off_deg``) says how far the fitted face plane's normal
lies from the scenario's face: a plane fitted to a rock jumble's sides turns the face's ordinary
relief into columns that cross the ground more than once.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from fsw.core.map.face_map import FaceMap
from fsw.core.map.overhang import FLAG_TESTS
from hil_sim.team.face_eval import (
    air_along_normal,
    facing_seen,
    frame_off_deg,
    overhang_in_cell,
    overhang_shown,
    relief_rise,
    truth_along_normal,
)
from hil_sim.team.face_scene import FaceScene
from hil_sim.world.world import World

F64 = NDArray[np.float64]
FRAME_OFF_DEG = 20.0  # a fitted face normal farther than this from the scenario's face: not the face
FALSE_CLASSES = ("part", "wrong_surface", "step", "other")  # what the truth holds under a false flag
REASONS = ("unobservable", "facing_far", "facing_unresolved", "no_inner", "both_one_view", "both_across",
           "facing_few", "air_few", "neighbour_flagged", "handed_over", "spread")


class WhyScene(FaceScene):
    """A :class:`FaceScene` that keeps each fused view's points in the face frame, and which
    agent took each view."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.kept: list[tuple[F64, F64, F64]] = []  # per view: face q (N, 3), var_w (N,), routed to face (N,)
        self.agents: list[str] = []  # per view (as ``true_rays``): the agent that took it
        self.flag_agent: NDArray[np.object_] | None = None  # per face cell: the agent whose view flagged it

    def _view(self, agent: str, *args: Any) -> None:
        self.agents.append(agent)
        super()._view(agent, *args)

    def _fuse(self, agent: str, parts: Any, eye: F64, window_rad: float) -> None:
        assert self.face is not None
        if self.flag_agent is None:
            self.flag_agent = np.full(self.face.grid.shape, "", object)
        before = self.face.overhang.copy()
        if parts:
            xyz = np.concatenate([p[0] for p in parts])
            cov = np.concatenate([p[1] for p in parts])
            q = self.face.frame.to_face(xyz)
            var_w = self.face.frame.cov_to_face(cov)[:, 2, 2]
            to_face, _ = self.face.routes(xyz)
            self.kept.append((q, var_w, to_face))
        super()._fuse(agent, parts, eye, window_rad)
        self.flag_agent[self.face.overhang & ~before] = agent


def facing_seen_by(world: World, face: FaceMap, rays: list[tuple[F64, F64]], agents: list[str]
                   ) -> dict[str, NDArray[np.bool_]]:
    """Per agent (``recon``, ``cliffbot``), per face cell (flat), whether one of its views' true
    sight lines ends in the cell on ground that faces the face (``face_eval.facing_seen`` on that
    agent's views; ``agents``: the agent of each of ``rays``)."""
    return {a: facing_seen(world, face, [r for r, who in zip(rays, agents, strict=True) if who == a])
            for a in ("recon", "cliffbot")}


def first_crossing(world: World, face: FaceMap, cells: NDArray[np.intp], reach_m: float = 0.25,
                   step_m: float = 0.005) -> F64:
    """Where the normal through each cell centre first leaves the true ground (the inner surface
    of an overhang; NaN: none)."""
    ws, air = air_along_normal(world, face, cells, reach_m, step_m)
    up = ~air[:, :-1] & air[:, 1:]
    has = up.any(axis=1)
    return np.where(has, ws[np.argmax(up, axis=1)] + 0.5 * step_m, np.nan)


def miss_reasons(scene: WhyScene) -> dict[str, Any]:
    """Counts of the reasons (module docstring) over the scene's missed truth overhang cells, and
    the truth, flagged and missed counts."""
    face = scene.face
    out: dict[str, Any] = {"seed": scene.seed, "truth": 0, "flagged": 0, "missed": 0, "frame_off_deg": None}
    out.update({f"has_{r}": 0 for r in REASONS})
    out.update({f"primary_{r}": 0 for r in REASONS})
    if face is None:
        return out
    off = frame_off_deg(scene.world, face)
    out["frame_off_deg"] = None if off is None else round(off, 1)
    g = face.grid
    cells = np.flatnonzero(face.map.mapped.reshape(-1))
    w_out, over = truth_along_normal(scene.world, face, cells)
    flagged = face.overhang.reshape(-1)[cells]
    shown = overhang_shown(scene.world, face, cells, w_out, over, scene.true_rays)
    out["truth"], out["flagged"] = int(over.sum()), int((over & flagged).sum())
    miss = over & ~flagged
    out["missed"] = int(miss.sum())
    mc = cells[miss]
    if mc.size == 0:
        return out
    w_in = first_crossing(scene.world, face, mc)
    w_o = w_out[miss]
    gap = face.cfg.overhang_gap_m
    half = 0.5 * gap
    index = {int(c): k for k, c in enumerate(mc)}
    m = len(mc)
    near_in = np.zeros((len(scene.kept), m), bool)
    near_out = np.zeros((len(scene.kept), m), bool)
    grav_in = np.zeros(m, bool)
    grav_out = np.zeros(m, bool)
    face_in = np.zeros(m, bool)
    face_out = np.zeros(m, bool)
    ws: list[list[float]] = [[] for _ in range(m)]
    vs: list[list[float]] = [[] for _ in range(m)]
    for k, (q, var_w, to_face) in enumerate(scene.kept):
        iy, ix, inside = g.cell_index(q[:, 0], q[:, 1])
        c = np.where(inside, iy * g.nx + ix, -1)
        for j in np.flatnonzero(np.isin(c, mc)):
            i = index[int(c[j])]
            a_in = abs(q[j, 2] - w_in[i]) < half
            a_out = abs(q[j, 2] - w_o[i]) < half
            near_in[k, i] |= a_in
            near_out[k, i] |= a_out
            if to_face[j]:
                face_in[i] |= a_in
                face_out[i] |= a_out
                ws[i].append(float(q[j, 2]))
                vs[i].append(float(var_w[j]))
            else:
                grav_in[i] |= a_in
                grav_out[i] |= a_out
    flag2 = face.overhang
    pad = np.pad(flag2, 1)
    nb = np.zeros(g.shape, bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                nb |= pad[1 + dy:1 + dy + g.ny, 1 + dx:1 + dx + g.nx]
    facing = face.facing.reshape(-1)[mc]
    air = face.air.reshape(-1)[mc]
    has: dict[str, NDArray[np.bool_]] = {}
    has["unobservable"] = ~shown[miss]
    seen = facing_seen_by(scene.world, face, scene.true_rays, scene.agents)
    unresolved = (seen["recon"] | seen["cliffbot"])[mc] & (facing == 0)
    has["facing_far"] = unresolved & ~seen["cliffbot"][mc]
    has["facing_unresolved"] = unresolved & seen["cliffbot"][mc]
    has["no_inner"] = ~near_in.any(axis=0) & (facing == 0) & (air == 0)
    has["both_one_view"] = (near_in & near_out).any(axis=0)
    has["both_across"] = near_in.any(axis=0) & near_out.any(axis=0) & ~has["both_one_view"]
    has["facing_few"] = (facing > 0) & (facing < face.cfg.facing_min_points)
    has["air_few"] = (air > 0) & (air < face.cfg.air_min_rays)
    has["neighbour_flagged"] = nb.reshape(-1)[mc]
    has["handed_over"] = (grav_in & ~face_in) | (grav_out & ~face_out)
    spread = np.zeros(m, bool)
    for i in range(m):
        if len(ws[i]) >= 2:
            w = np.asarray(ws[i])
            s = 3.0 * np.sqrt(np.median(vs[i]))
            spread[i] = np.percentile(w, 95) - np.percentile(w, 5) > gap + s
    has["spread"] = spread
    taken = np.zeros(m, bool)
    for r in REASONS:
        out[f"has_{r}"] = int(has[r].sum())
        out[f"primary_{r}"] = int((has[r] & ~taken).sum())
        taken |= has[r]
    out["primary_none"] = int((~taken).sum())
    return out


def false_flags(scene: WhyScene) -> dict[str, int]:
    """The scene's false flags (flagged face cells whose normal through the centre crosses the
    true ground once) sorted by the test that flagged each (``fsw.core.map.overhang.FLAG_TESTS``:
    ``ff_<test>``), the agent whose view did (``ff_<test>_<agent>``) and what the truth holds
    there, the first that applies (``ff_<test>_<class>``, :data:`FALSE_CLASSES`)."""
    out = {f"ff_{t}{k}": 0 for t in FLAG_TESTS[1:]
           for k in ("", "_recon", "_cliffbot", *(f"_{c}" for c in FALSE_CLASSES))}
    face = scene.face
    if face is None or scene.flag_agent is None:
        return out
    cells = np.flatnonzero(face.map.mapped.reshape(-1))
    w_true, over = truth_along_normal(scene.world, face, cells)
    false = face.overhang.reshape(-1)[cells] & ~over
    fc = cells[false]
    if fc.size == 0:
        return out
    gap = face.cfg.overhang_gap_m
    part = overhang_in_cell(scene.world, face, fc)
    off = ~(np.abs(face.map.z.reshape(-1)[fc] - w_true[false]) <= gap)
    step = relief_rise(scene.world, face)[fc] >= gap
    cls = np.where(part, 0, np.where(off, 1, np.where(step, 2, 3)))
    test = face.flagged_by.reshape(-1)[fc]
    agent = scene.flag_agent.reshape(-1)[fc]
    for k in range(len(fc)):
        t = FLAG_TESTS[int(test[k])]
        out[f"ff_{t}"] += 1
        out[f"ff_{t}_{FALSE_CLASSES[int(cls[k])]}"] += 1
        if agent[k] in ("recon", "cliffbot"):
            out[f"ff_{t}_{agent[k]}"] += 1
    return out


def why_scene(spec: str, seed: int, config: str, n_recon: int, n_cliff: int,
              resolve_cells: float | None = None) -> dict[str, Any]:
    """One scene's miss reasons and its false flags (deterministic per seed)."""
    s = WhyScene(spec, seed, config, resolve_cells=resolve_cells)
    row = s.measure(n_recon, n_cliff)
    return {**miss_reasons(s), "false": row["overhang_false"], "false_part": row["overhang_false_part"],
            **false_flags(s)}


def false_report(rows: list[dict[str, Any]], table: Any) -> str:
    """The pooled false flags by the test that flagged them, the agent and the truth's class."""
    out = []
    for t in FLAG_TESTS[1:]:
        n = sum(r.get(f"ff_{t}", 0) for r in rows)
        row: dict[str, Any] = {"test": t, "false flags": n}
        for k in ("recon", "cliffbot", *FALSE_CLASSES):
            row[k] = sum(r.get(f"ff_{t}_{k}", 0) for r in rows)
        out.append(row)
    return ("## False flags by the test that flagged them\n\n"
            "Per test, the agent whose view flagged the cell and what the truth holds there (the first "
            "that applies): `part`, an overhang covers part of the cell off its centre; `wrong_surface`, "
            "the map's height lies more than the gap off the true surface (the cell holds a surface "
            "the ground does not have there); `step`, a true rise of the gap or more within 2 cells; "
            "`other`, none of these.\n\n"
            + table(out, ["test", "false flags", "recon", "cliffbot", *FALSE_CLASSES]) + "\n\n")


def why_report(rows: list[dict[str, Any]], table: Any) -> str:
    """The pooled reasons (each reason: the missed cells that have it, and those for which it is
    the first in the order of the module docstring), the cells in scenes whose fitted frame is
    not the face's (``FRAME_OFF_DEG``) and the per-scene table."""
    missed = sum(r["missed"] for r in rows)
    summary = [{"figure": "truth overhang cells", "cells": sum(r["truth"] for r in rows)},
               {"figure": "flagged", "cells": sum(r["flagged"] for r in rows)},
               {"figure": "missed", "cells": missed},
               {"figure": "false flags (of them, an overhang covers part of the cell)",
                "cells": f"{sum(r['false'] for r in rows)} ({sum(r['false_part'] for r in rows)})"}]
    for k in REASONS:
        summary.append({"figure": f"missed: {k}", "cells": sum(r[f"has_{k}"] for r in rows),
                        "first reason": sum(r[f"primary_{k}"] for r in rows)})
    summary.append({"figure": "missed: none of these", "cells": "",
                    "first reason": sum(r.get("primary_none", 0) for r in rows)})
    off = [r for r in rows if r["frame_off_deg"] is not None and r["frame_off_deg"] > FRAME_OFF_DEG]
    summary.append({"figure": f"truth overhang cells in scenes whose fitted face normal is more than "
                              f"{FRAME_OFF_DEG:g} deg off the face (flagged, missed)",
                    "cells": f"{sum(r['truth'] for r in off)} ({sum(r['flagged'] for r in off)}, "
                             f"{sum(r['missed'] for r in off)})"})
    cols = ["seed", "frame_off_deg", "truth", "flagged", "missed", "false", "false_part",
            *(f"primary_{k}" for k in REASONS)]
    return ("## Why truth overhang cells were missed\n\n" + table(summary, ["figure", "cells", "first reason"])
            + "\n\n" + false_report(rows, table)
            + "## Scenes (first reason per missed cell)\n\n" + table(rows, cols) + "\n")
