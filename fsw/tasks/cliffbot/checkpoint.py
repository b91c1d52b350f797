"""The Cliff-bot mission's checkpoint: its state, its navigation estimate and the received map.

Two files in ``[checkpoint] directory``: ``cliffbot_state.json`` (schema 1: the mission's
state, legs, targets with what became of them, the estimate and its covariance, the ground it
stood on, the way it came since it left its start) and
``cliffbot_map.npy`` (the received map, heights in the team's frame). Each is written to a
temporary name and renamed over the old one, the map first, so a crash leaves the previous
pair or the new one. The radio task keeps a third, ``cliffbot_sync.json``: its map sync end's
state (``fsw.comm.team.sync_end.FlightSync.state``), written after each sync round of its own
and as the RECON-bot's tiles arrive. A file that is missing, unreadable or inconsistent is refused with one
line (:class:`CheckpointError`), never a traceback; the mission then starts afresh.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import MapGrid
from fsw.core.team.contact_ground import StoodGround
from fsw.framework.storage import describe
from fsw.tasks.cliffbot.legs import Leg
from fsw.tasks.cliffbot_mission import CliffbotMission, Estimate

SCHEMA = 1
STATE, MAP, SYNC = "cliffbot_state.json", "cliffbot_map.npy", "cliffbot_sync.json"
STATES = ("WAIT_MAP", "SENSE", "PLAN", "WAIT_FIX", "DRIVE", "DWELL", "DONE", "SAFE")


class CheckpointError(ValueError):
    """A checkpoint that cannot be used (one line)."""


def snapshot(m: CliffbotMission, now: float) -> dict[str, object]:
    """What the checkpoint keeps of the mission (JSON-ready)."""
    return {
        "schema": SCHEMA, "time_s": round(now, 6), "state": m.state, "safe_reason": m.safe_reason,
        "leg_i": m.leg_i, "fix_seq": m.fix_seq, "map_version": m.map_version, "error_bound_m": m.error_bound_m,
        "start": [float(v) for v in m.start], "targets": m.targets.tolist(), "reached": list(m.reached),
        "reasons": list(m.reasons), "legs": [[float(g.goal[0]), float(g.goal[1]), g.target] for g in m.legs],
        "nav_s": [float(v) for v in m.est.s], "nav_P": m.est.P.tolist(),
        # the map's cells no sensor measured (the plane carried under its body): flat indices
        "carried": [] if m.carried is None else np.flatnonzero(m.carried).tolist(),
        # the ground it stood on (fsw.core.team.contact_ground.StoodGround): flat indices, heights,
        # and which of them it knew by contact
        "stood": [] if m.stood is None else _stood(m.stood),
        # the way it came since it left its start (CliffbotMission.trail): lengths and estimate
        "trail": [list(t) for t in m.trail],
        # places the tension guard refused (CliffbotMission.refused): x, y and the limit neared
        "refused": [[float(xy[0]), float(xy[1]), why] for xy, why in m.refused],
    }


def _stood(g: StoodGround) -> list[list[float]]:
    at = np.flatnonzero(np.isfinite(g.z))
    return [[int(i), float(g.z.flat[i]), int(g.by_contact.flat[i])] for i in at]


def restore(m: CliffbotMission, st: dict[str, object], z: NDArray[np.float64] | None, grid: MapGrid) -> str:
    """Put the checkpoint's state into a fresh mission; a leg under way asks for a fix first.
    Returns a one-line summary; :class:`CheckpointError` if the state does not fit."""
    try:
        if st.get("schema") != SCHEMA:
            raise CheckpointError(f"schema {st.get('schema')!r}, expected {SCHEMA}")
        state = str(st["state"])
        if state not in STATES:
            raise CheckpointError(f"unknown state {state!r}")
        targets = np.asarray(st["targets"], float).reshape(-1, 2)
        s = np.asarray(st["nav_s"], float).reshape(3)
        p = np.asarray(st["nav_P"], float).reshape(3, 3)
        legs = [_leg(v) for v in _list(st["legs"])]
        reached = [bool(v) for v in _list(st["reached"])]
        reasons = [str(v) for v in _list(st["reasons"])]
        leg_i = _int(st["leg_i"])
    except (KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"{STATE}: {type(exc).__name__}: {exc}") from None
    if not (np.isfinite(s).all() and np.isfinite(p).all() and np.isfinite(targets).all()):
        raise CheckpointError(f"{STATE}: non-finite estimate or targets")
    if len(reached) != len(targets) or len(reasons) != len(targets) or not 0 <= leg_i <= len(legs):
        raise CheckpointError(f"{STATE}: targets, legs and their results do not agree")
    if state not in ("WAIT_MAP",) and z is None:
        raise CheckpointError(f"state {state} without {MAP}")
    if z is not None:
        if z.shape != grid.shape:
            raise CheckpointError(f"{MAP}: shape {z.shape}, the map grid is {grid.shape}")
        m.z, m.grid, m.map_version = np.asarray(z, np.float64), grid, _int(st.get("map_version", 1))
        bound = st.get("error_bound_m", 0.0)  # the map's error bound: the tension margins rest on it
        m.error_bound_m = float(bound) if isinstance(bound, (int, float)) and math.isfinite(bound) else 0.0
        try:
            flat = np.asarray(st.get("carried", []), np.int64).reshape(-1)
        except (TypeError, ValueError) as exc:
            raise CheckpointError(f"{STATE}: carried: {type(exc).__name__}: {exc}") from None
        if flat.size and (flat.min() < 0 or flat.max() >= z.size):
            raise CheckpointError(f"{STATE}: carried cells outside the map")
        m.carried = np.zeros(grid.shape, bool)
        m.carried.flat[flat] = True
        m.stood = _restore_stood(st.get("stood", []), grid)
    m.trail = _restore_trail(st.get("trail", []))
    m.refused = _restore_refused(st.get("refused", []))
    m.targets, m.reached, m.reasons, m.legs, m.leg_i = targets, reached, reasons, legs, leg_i
    m.planned_lengths = [math.inf for _ in range(len(targets))]
    m.looks = [0 for _ in range(len(targets))]
    m.start = np.asarray(st.get("start", m.start), float).reshape(2)
    m.est = Estimate(s, p)  # (the navigation task reads the same checkpoint: nav_estimate)
    m.fix_seq = _int(st.get("fix_seq", 0))
    if state in ("WAIT_FIX", "DRIVE", "DWELL") or (state == "SENSE" and legs):
        state = "WAIT_FIX"  # the leg goes on from the estimate, after a fix (and its views)
    elif state == "SENSE":
        state = "SENSE" if m.sensing is not None else "PLAN"  # the views before the plan are asked again
    m.state = state
    m.safe_reason = str(st.get("safe_reason", "")) if state == "SAFE" else ""
    return f"leg {leg_i + 1} of {len(legs)}, {sum(reached)} of {len(targets)} targets reached"


def _restore_refused(v: object) -> list[tuple[NDArray[np.float64], str]]:
    if not isinstance(v, list):
        raise CheckpointError(f"{STATE}: refused: expected a list, got {type(v).__name__}")
    out = []
    for row in v:
        if not isinstance(row, list) or len(row) != 3 or row[2] not in ("slack", "over-tension"):
            raise CheckpointError(f"{STATE}: refused: expected [x, y, 'slack' or 'over-tension'], got {row!r}")
        try:
            xy = np.array([float(row[0]), float(row[1])])
        except (TypeError, ValueError) as exc:
            raise CheckpointError(f"{STATE}: refused: {type(exc).__name__}: {exc}") from None
        if not np.isfinite(xy).all():
            raise CheckpointError(f"{STATE}: refused: a non-finite place")
        out.append((xy, str(row[2])))
    return out


def _restore_trail(v: object) -> list[tuple[float, float, float, float]]:
    """The way it came, from its checkpoint form (``[length a, length b, x, y]`` per entry)."""
    try:
        rows = np.asarray(v, np.float64).reshape(-1, 4)
    except (TypeError, ValueError) as exc:
        raise CheckpointError(f"{STATE}: trail: {type(exc).__name__}: {exc}") from None
    if not np.isfinite(rows).all() or (rows[:, :2] < 0.0).any():
        raise CheckpointError(f"{STATE}: trail: non-finite values or a negative length")
    return [(float(r[0]), float(r[1]), float(r[2]), float(r[3])) for r in rows]


def _restore_stood(v: object, grid: MapGrid) -> StoodGround:
    """The ground stood on, from its checkpoint form (``[index, height, by contact]`` per cell)."""
    g = StoodGround.empty(grid.shape)
    try:
        rows = np.asarray(v, np.float64).reshape(-1, 3)
    except (TypeError, ValueError) as exc:
        raise CheckpointError(f"{STATE}: stood: {type(exc).__name__}: {exc}") from None
    if not np.isfinite(rows).all():
        raise CheckpointError(f"{STATE}: stood: non-finite values")
    idx = rows[:, 0].astype(np.int64)
    if len(idx) and (idx.min() < 0 or idx.max() >= g.z.size or not np.array_equal(idx, rows[:, 0])):
        raise CheckpointError(f"{STATE}: stood cells outside the map")
    g.z.flat[idx] = rows[:, 1]
    g.by_contact.flat[idx] = rows[:, 2] != 0
    return g


def nav_estimate(st: dict[str, object]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The checkpoint's navigation estimate ``(s, P)``; :class:`CheckpointError` if unusable."""
    try:
        s = np.asarray(st["nav_s"], float).reshape(3)
        p = np.asarray(st["nav_P"], float).reshape(3, 3)
    except (KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"{STATE}: {type(exc).__name__}: {exc}") from None
    if st.get("schema") != SCHEMA or not (np.isfinite(s).all() and np.isfinite(p).all()):
        raise CheckpointError(f"{STATE}: no usable estimate")
    return s, p


def _list(v: object) -> list[object]:
    if not isinstance(v, list):
        raise TypeError(f"expected a list, got {type(v).__name__}")
    return v


def _leg(v: object) -> Leg:
    """``[x, y, target or None]``."""
    a, b, t = _list(v)
    return Leg(np.array([_float(a), _float(b)]), None if t is None else _int(t))


def _float(v: object) -> float:
    if not isinstance(v, int | float):
        raise TypeError(f"expected a number, got {type(v).__name__}")
    return float(v)


def _int(v: object) -> int:
    if not isinstance(v, int | float | str):
        raise TypeError(f"expected a number, got {type(v).__name__}")
    return int(v)


class CheckpointFile:
    """The checkpoint's two files in ``directory`` ("" : no checkpoints)."""

    def __init__(self, directory: str) -> None:
        self.dir = Path(directory) if directory else None

    @property
    def enabled(self) -> bool:
        return self.dir is not None

    def save(self, state: dict[str, object], z: NDArray[np.float64] | None) -> str:
        """Write both files; returns "" or the one-line reason they were not written."""
        if self.dir is None:
            return ""
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            if z is not None:
                self._atomic(MAP, lambda f: np.save(f, np.asarray(z, np.float64)))
            else:
                (self.dir / MAP).unlink(missing_ok=True)
            self._atomic(STATE, lambda f: f.write(json.dumps(state).encode()))
        except OSError as exc:
            return describe(exc)
        return ""

    def save_sync(self, state: dict[str, object]) -> str:
        """Write the map sync end's state; returns "" or the one-line reason it was not written."""
        if self.dir is None:
            return ""
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            self._atomic(SYNC, lambda f: f.write(json.dumps(state).encode()))
        except OSError as exc:
            return describe(exc)
        return ""

    def load_sync(self) -> dict[str, object] | None:
        """The map sync end's state (None: there is none); :class:`CheckpointError` if unreadable."""
        if self.dir is None or not (self.dir / SYNC).exists():
            return None
        try:
            st = json.loads((self.dir / SYNC).read_text())
            if not isinstance(st, dict):
                raise ValueError("not a JSON object")
        except (OSError, ValueError) as exc:
            raise CheckpointError(f"{self.dir / SYNC}: {type(exc).__name__}: {exc}") from None
        return st

    def _atomic(self, name: str, write: Callable[[BinaryIO], object]) -> None:
        assert self.dir is not None
        tmp = self.dir / f".{name}.tmp"
        try:
            with open(tmp, "wb") as f:
                write(f)
                f.flush()
                os.fsync(f.fileno())
            tmp.replace(self.dir / name)
        finally:
            tmp.unlink(missing_ok=True)

    def load(self) -> tuple[dict[str, object], NDArray[np.float64] | None] | None:
        """The checkpoint in the directory (None: there is none); :class:`CheckpointError` if
        it is unreadable."""
        if self.dir is None or not (self.dir / STATE).exists():
            return None
        try:
            st = json.loads((self.dir / STATE).read_text())
            if not isinstance(st, dict):
                raise ValueError("not a JSON object")
            z = None
            if (self.dir / MAP).exists():
                z = np.asarray(np.load(self.dir / MAP, allow_pickle=False), np.float64)
        except (OSError, ValueError) as exc:
            raise CheckpointError(f"{self.dir}: {type(exc).__name__}: {exc}") from None
        return st, z
