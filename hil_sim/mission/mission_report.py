"""A mission's report, lockstep or (from its newest checkpoint, :func:`checkpoint_report`) real
time: the foreground and timing figures, the map-error plane, the Cliff-bot's report and the
output files (``summary.json`` and its PNGs; docs/experiments.md).

Each output file is written under a temporary name and renamed, so a full or failing disk
(``ENOSPC``, ``EIO``) leaves the previous file or none, never half of one. A picture that
cannot be written is a ``REPORT_FILE_NOT_SAVED`` line on stderr and an entry of the summary's
``write_errors``; a summary that cannot be written raises
:class:`fsw.framework.storage.StorageError` (one line; the run's checkpoints still hold it).
"""

from __future__ import annotations

import dataclasses
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from fsw.core.geometry import MapGrid
from fsw.framework.storage import StorageError, describe
from hil_sim.lab.terrain_eval import fit_plane

WALL_CLOCK_FIELDS = ("wall_s", "task_max_ms", "task_ms_per_frame", "slips", "overruns")


def task_ms_per_frame(exe: Any) -> dict[str, float]:
    """Foreground cost: each task's summed execution time on the host timer over the frames
    run, ms per frame, plus ``total`` (every task); slack-job slices are not foreground and not
    counted."""
    frames = max(1, int(exe.frame))
    tasks = [t for rg in exe.groups for t in rg.members]
    out = {t.name: round(t.host.total_s * 1e3 / frames, 4) for t in tasks}
    out["total"] = round(sum(t.host.total_s for t in tasks) * 1e3 / frames, 4)
    return out


def error_plane(grid: MapGrid, err: Any, mapped: Any) -> tuple[float | None, float | None]:
    """The plane fitted (least squares) to the map's error over mapped cells: its tilt (deg,
    the part of the error a tilted map explains) and the RMS error left around it (m)."""
    fit = fit_plane(grid, err, mapped) if int(mapped.sum()) >= 10 else None
    if fit is None:
        return None, None
    coef, resid = fit
    return (round(float(np.degrees(np.arctan(np.hypot(coef[0], coef[1])))), 4),
            round(float(np.sqrt(np.mean(resid**2))), 5))


def task_max_ms(exe: Any) -> dict[str, float]:
    """Max execution time on the host timer per task, plus the longest frame (``frame``:
    foreground and slack) and the longest slack-job slice overall (``slack_slice``) and per
    submitting task (``slack_slice.<task>``), ms."""
    out = {n: round(t.host.max_s * 1e3, 3) for n, t in exe.tasks.items()}
    out["frame"] = round(exe.host_frame_max_s * 1e3, 3)
    out["slack_slice"] = round(exe.jobs.host_max_slice_s * 1e3, 3)
    for owner, s in sorted(exe.jobs.host_max_slice_by_owner.items()):
        out[f"slack_slice.{owner}"] = round(s * 1e3, 3)
    return out


def _cliffbot_report(cliffbot: Any, out: Path | None) -> dict[str, Any] | None:
    """The Cliff-bot's last report, its figure named relative to the run directory."""
    if not cliffbot.reports:
        return None
    rep = dataclasses.asdict(cliffbot.reports[-1])
    if rep.get("png") and out is not None:
        rep["png"] = Path(rep["png"]).name
    return rep


def map_transfer(mission: Any) -> str:
    """How the map transfer to the Cliff-bot ended: ``delivered``, the link's final state
    (``failed``, ``rejected``), ``timeout`` (TRANSMIT gave up waiting), or ``none`` (not sent)."""
    ev = [e for e in mission.ctx.events.history if e.name == f"{mission.name}.TRANSMITTED"]
    if not ev:
        return "none"
    state = ev[-1].text.rsplit(": ", 1)[-1]  # "map transmission ended: STATE"
    return "delivered" if state == "done" else state


def transfer_s(mission: Any) -> float | None:
    """Bench seconds from the end of mapping to the end of the map transfer (None: not sent)."""
    hist = mission.ctx.events.history
    end = [e.time_s for e in hist if e.name == f"{mission.name}.END"]
    sent = [e.time_s for e in hist if e.name == f"{mission.name}.TRANSMITTED"]
    return round(sent[-1] - end[-1], 3) if end and sent else None


def write_outputs(out: Path, summary: dict[str, Any], emap: Any, truth: Any, grid: MapGrid,
                  extra_files: dict[str, str] | None = None) -> dict[str, str]:
    """summary.json and the PNGs: map, variance, error, coverage over steps; ``extra_files``
    (name -> file) are listed in ``files`` too."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = {"summary": "summary.json", "map": "map.png", "coverage": "coverage.png", **(extra_files or {})}
    ext = grid.extent
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6), constrained_layout=True)
    for ax, data, title, cmap in (
        (axes[0], emap.z, "elevation (m)", "terrain"),
        (axes[1], np.sqrt(emap.var), "sigma (m)", "magma"),
        (axes[2], emap.z - truth, "error vs truth (m)", "coolwarm"),
    ):
        kw = {"vmin": -0.05, "vmax": 0.05} if "error" in title else {}
        if "sigma" in title:
            kw = {"vmin": 0.0, "vmax": 0.03}
        im = ax.imshow(np.where(emap.mapped, data, np.nan), origin="lower", extent=ext, cmap=cmap, **kw)
        ax.set_title(title)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        fig.colorbar(im, ax=ax, shrink=0.8)
    for r in summary["steps"]:
        axes[0].plot(r["pose"]["x"], r["pose"]["y"], "k^", ms=5)
    fig.suptitle(
        f"{summary['scenario']} method {summary['method']} seed {summary['seed']}: "
        f"{summary['mapped_cells']} cells mapped"
    )
    errors: list[str] = []
    _save(out / files["map"], lambda p: fig.savefig(p, dpi=90), errors)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6, 4), constrained_layout=True)
    st = summary["steps"]
    ax.plot([r["step"] for r in st], [r["mapped_cells"] for r in st], "o-", label="mapped cells")
    ax.bar([r["step"] for r in st], [r["obtained_new_cells"] for r in st], alpha=0.3, label="obtained new")
    ax.plot([r["step"] for r in st], [r["expected_new_cells"] for r in st], "x--", label="expected new (H)")
    ax.set_xlabel("stereo imaging step")
    ax.set_ylabel("cells")
    ax.legend()
    ax.grid(alpha=0.3)
    _save(out / files["coverage"], lambda p: fig.savefig(p, dpi=90), errors)
    plt.close(fig)
    files["error"] = "map_error.npy"  # map minus truth on mapped cells (NaN elsewhere), float32
    err = np.where(emap.mapped, emap.z - truth, np.nan).astype(np.float32)
    _save(out / files["error"], lambda p: np.save(p, err), errors)
    summary["files"] = files
    if errors:
        summary["write_errors"] = errors
    text = json.dumps(summary, indent=2) + "\n"
    try:
        _save(out / files["summary"], lambda p: p.write_text(text), None)
    except OSError as exc:
        raise StorageError(exc.errno, f"{out / files['summary']} not written: {describe(exc)}") from None
    return files


#: views whose expected new cells are no prediction of the view taken (issue 30 item 3)
UNRATED_VIEWS = frozenset({"", "look", "part-way", "stay", "panorama"})


def prediction_ratios(steps: list[dict[str, Any]]) -> dict[str, Any]:
    """Obtained over expected new cells of the rated views (the planner's own, at the pose it
    rated, with a prediction > 0): count, median and 10th-90th percentile of the per-step
    ratio; and what the unrated views (looks, refused moves: expected 0) obtained, which an
    aggregate over all steps would count against the model."""
    rated = [s for s in steps if s.get("view", "") not in UNRATED_VIEWS
             and float(s.get("expected_new_cells", 0.0)) > 0.0 and int(s.get("view_new_cells", -1)) >= 0]
    ratios = np.array([s["view_new_cells"] / s["expected_new_cells"] for s in rated], np.float64)
    unrated = [s for s in steps if s not in rated and int(s.get("step", 1)) >= 1]  # step 0: the panorama
    out: dict[str, Any] = {"rated_steps": len(rated), "unrated_steps": len(unrated),
                           "unrated_new_cells": int(sum(int(s.get("obtained_new_cells", 0)) for s in unrated))}
    if ratios.size:
        p10, med, p90 = np.percentile(ratios, [10, 50, 90])
        out.update(median_ratio=float(med), p10_ratio=float(p10), p90_ratio=float(p90))
    return out


def _save(path: Path, write: Callable[[Path], Any], errors: list[str] | None) -> None:
    """``write`` to a temporary name, then rename over ``path``; a failure removes the
    temporary and is reported (stderr, ``errors``) or, with ``errors=None``, raised."""
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    try:
        write(tmp)
        tmp.replace(path)
    except OSError as exc:
        if errors is None:
            raise
        errors.append(f"{path.name}: {describe(exc)}")
        print(f"safer-hil: REPORT_FILE_NOT_SAVED {path}: {describe(exc)}", file=sys.stderr)
    finally:
        tmp.unlink(missing_ok=True)


def strip_wall_clock(summary: dict[str, Any]) -> dict[str, Any]:
    """The summary without its wall-clock fields (for determinism checks)."""
    out = {k: v for k, v in summary.items() if k not in WALL_CLOCK_FIELDS}
    out["steps"] = [{k: v for k, v in s.items() if k not in WALL_CLOCK_FIELDS} for s in summary["steps"]]
    return out


def checkpoint_report(out: Path, checkpoint_dir: Path, world: Any, *, scenario: str, seed: int, method: str,
                      datum_m: float, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """A real-time mission's ``summary.json`` and pictures (``safer-hil serve --out``): the same
    files and the same schema as a lockstep run's, from the flight's newest checkpoint (its map)
    and the newest one with the mission's section (its step records; the perception task's own
    checkpoints carry the map alone) against the bench's truth. What only the flight executive knows in
    real time (slips, overruns, task timing, frames) is not in a checkpoint: those fields are null.
    ``ValueError`` (one line) when no checkpoint can be read."""
    from fsw.core.map.checkpoint import CheckpointConfig, CheckpointError, decode
    from fsw.drivers.map_store import MapStore
    from hil_sim.lab.terrain_eval import map_quality

    store = MapStore(CheckpointConfig(directory=str(checkpoint_dir)))
    loaded = store.load_latest()
    if loaded.emap is None:
        why = f" ({loaded.skipped[-1][1]})" if loaded.skipped else ""
        raise ValueError(f"{checkpoint_dir}: no readable mission checkpoint{why}: no report")
    emap = loaded.emap
    grid = emap.grid
    state: dict[str, Any] = {}
    for path in reversed(store.paths()):  # the newest checkpoint with the mission's section
        try:
            meta = decode(path.read_bytes())[1]
        except (CheckpointError, OSError):
            continue
        if isinstance(meta.state, dict) and isinstance(meta.state.get("mission"), dict):
            state = meta.state
            break
    mission: dict[str, Any] = state.get("mission") or {}
    steps = [dict(r) for r in mission.get("records", []) if isinstance(r, dict)]
    truth = world.truth_on_grid(grid)
    truth_f = truth - datum_m
    mapped = emap.mapped & np.isfinite(truth)
    rmse = float(np.sqrt(np.mean((emap.z[mapped] - truth_f[mapped]) ** 2))) if mapped.any() else None
    tilt_deg, rmse_plane = error_plane(grid, emap.z - truth_f, mapped)
    quality = map_quality(emap, truth, [], datum_m)
    summary: dict[str, Any] = {
        "schema": 1, "scenario": scenario, "method": method, "seed": seed, "camera": "config",
        "clock": "real time", "checkpoint": loaded.path.name if loaded.path is not None else None,
        "steps": steps, "prediction": prediction_ratios(steps),
        "map_rmse_m": rmse, "map_error_tilt_deg": tilt_deg, "map_rmse_detilted_m": rmse_plane,
        "calib_2sigma": quality["within_2sigma"], "map_quality": quality,
        "geofence_refusals": mission.get("edge_violations"), "looks": mission.get("looks"),
        "stays": mission.get("stays"), "end_reason": mission.get("end"), "safe_reason": mission.get("safe_reason"),
        "safe_entries": mission.get("safe_entries"), "final_state": mission.get("phase"),
        "mapped_cells": int(emap.mapped.sum()), "sim_s": loaded.meta.time_s if loaded.meta else None,
        "frames": state.get("frame"),
        "slips": None, "overruns": None, "task_max_ms": None, "task_ms_per_frame": None, "files": {},
        **(extra or {}),
    }
    summary = json.loads(json.dumps(summary, default=str))
    summary["files"] = write_outputs(out, summary, emap, truth_f, grid)
    return summary
