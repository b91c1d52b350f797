"""``safer-hil experiment camera-path``: which factor costs the map what (lockstep replays).

Runs one mission (``safer-hil run`` with the same options), records every merged view
(``hil_sim.lab.view_replay``) and merges the same views again with one factor changed at a time:
the calibration file (the estimate, or the renderer's TRUE calibration), the cameras (the
pairs re-rendered at the true pose through the ideal pinhole pair or the real lenses), the
flight's pose estimate or the true pose, registration and its station carry on or off.
Prints cells, map RMSE, error-plane tilt, 2-sigma fraction and station seams per row and
writes OUT/camera_path.json. The trajectory is the recorded mission's in every row.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from hil_sim.lab.results import command_line, markdown_table, write_results

HELP = "replay one mission's views with one factor changed at a time (camera path, poses, registration)"

ROWS = (
    ("recorded views, flight poses (the mission)", {}),
    ("TRUE calibration file", {"calibration_file": "TRUE"}),
    ("ideal cameras (re-rendered), no calibration", {"calibration_file": "", "cameras": "ideal"}),
    ("registration carry off", {"carry": False}),
    ("ideal cameras, carry off", {"calibration_file": "", "cameras": "ideal", "carry": False}),
    ("true poses", {"true_pose": True}),
    ("true poses, TRUE calibration", {"true_pose": True, "calibration_file": "TRUE"}),
    ("true poses, ideal cameras", {"true_pose": True, "calibration_file": "", "cameras": "ideal"}),
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from fsw.settings import DEFAULT_CONFIG

    p.add_argument("--scenario", default="lab", help="lab, cliff, mars or file:PATH")
    p.add_argument("--method", default="5", choices=("1", "2", "3", "4", "5", "oracle"))
    p.add_argument("--steps", type=int, default=20, help="imaging steps after the panorama")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--camera", default="config", choices=("config", "ideal"),
                   help="the cameras of the recorded mission")
    p.add_argument("--config", default=str(DEFAULT_CONFIG), help="flight configuration")
    p.add_argument("--out", type=Path, default=Path("out/camera_path"), help="mission and result directory")


def run(args: argparse.Namespace) -> int:
    from fsw.drivers.calibration_file import save_calibration
    from fsw.framework.params import ConfigError
    from fsw.settings import load_settings
    from hil_sim.camera_model import TrueCameras
    from hil_sim.lab.view_replay import Factor, record_mission, replay
    from hil_sim.mission.mission_run import RunSpec
    from hil_sim.rig import load_hardware

    if args.steps < 1:
        print("safer-hil experiment camera-path: --steps must be >= 1", file=sys.stderr)
        return 2
    try:
        cfg = load_settings(args.config)
    except (ConfigError, ValueError) as err:
        print(f"safer-hil experiment camera-path: {err}", file=sys.stderr)
        return 2
    spec = RunSpec(scenario=args.scenario, method=args.method, steps=args.steps, seed=args.seed,
                   config=args.config, out=args.out, camera=args.camera)
    summary, views = record_mission(spec)
    print(f"mission: {summary['mapped_cells']} cells, RMSE {100 * summary['map_rmse_m']:.2f} cm, "
          f"{len(views)} views recorded")
    true_cal = Path(tempfile.mkdtemp()) / "true_calibration.yaml"
    cams = TrueCameras.from_config(cfg.camera, load_hardware(spec.hardware).camera)
    save_calibration(true_cal, cams.truth())
    datum = float((summary.get("map_quality") or {}).get("datum_m") or 0.0)
    rows = []
    print(f"{'factor':48s} {'cells':>7s} {'RMSE cm':>8s} {'tilt deg':>8s} {'2 sigma':>8s} {'seam cm (max)':>14s}")
    for name, kw in ROWS:
        if args.camera == "ideal" and "calibration_file" not in kw and "cameras" not in kw:
            kw = {**kw, "calibration_file": ""}  # recorded ideal pairs are not to be rectified
        if kw.get("calibration_file") == "TRUE":
            if args.camera == "ideal":
                kw = {**kw, "cameras": "real"}
            kw = {**kw, "calibration_file": str(true_cal)}
        q = replay(views, args.scenario, args.seed, Factor(**kw), args.config, datum)
        rows.append({"factor": name, **q})
        seam = "-" if q["seam_m"] is None else f"{100 * q['seam_m']:.2f} ({100 * q['seam_max_m']:.1f})"
        print(f"{name:48s} {q['cells']:7d} {100 * q['rms_m']:8.2f} {q['tilt_err_deg']:8.2f} "
              f"{100 * q['within_2sigma']:7.1f}% {seam:>14s}", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "camera_path.json").write_text(json.dumps(rows, indent=1))
    write_results("camera-path", command_line("camera-path"), markdown_table(rows))
    return 0
