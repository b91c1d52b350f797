"""The information model's error split (hil_sim/lab/prediction_check.py, issue 30 item 3).

Requirements: a rated view's map update is found in the mission recording by its own new
cells; its obtained cells are counted, those outside the true field of view and depth range
apart; the model's sum of P_V and the cells the truth leaves visible are positive for a view of
open ground; the table reports each part; a bad --what-if key is refused.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np
import pytest

from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap
from ground.recording import MissionRecorder
from hil_sim.lab.prediction_check import ViewSplit, decompose_run, split_table


@dataclass
class _Nav:
    x: float = 0.0
    y: float = 0.0
    yaw: float = -math.pi / 2  # facing -y, toward the edge at y = -1
    roll: float = 0.0
    pitch: float = 0.0
    z_m: float = 0.0
    joints: tuple[float, float, float] = (0.0, -0.6, 0.5)


def test_a_view_is_split_against_the_truth(tmp_path) -> None:
    y = np.arange(200)[:, None] * 0.02 - 3.0 + 0.01
    np.save(tmp_path / "step.npy", (np.where(y > -1.0, 0.0, -0.5) + np.zeros((1, 200))).astype(np.float32))
    spec = f"file:{tmp_path / 'step.npy'}?cell_m=0.02&x_min_m=-1&y_min_m=-3&cliffbot.x_m=1.5&cliffbot.y_m=-2.2"
    grid = MapGrid(-1.0, -3.0, 0.03, 133, 133)
    ys, xs = grid.centers()[1], grid.centers()[0]
    before = np.where((np.abs(ys) < 0.5) & (np.abs(xs) < 0.6), 0.0, np.nan)
    ahead = np.isnan(before) & (ys < -2.3) & (ys > -2.8) & (np.abs(xs) < 0.3)  # in front of the camera
    behind = np.isnan(before) & (ys > 0.7) & (np.abs(xs) < 0.3)  # behind it: outside the view
    after = np.where(ahead | behind, 0.0, before)
    rec = MissionRecorder(tmp_path / "run" / "mission.mcap")
    src = rec.source("recon")
    for t, z in ((1.0, before), (2.0, after)):
        emap = ElevationMap(grid)
        emap.z, emap.n, emap.var = z, np.isfinite(z).astype(np.int32), np.where(np.isfinite(z), 1e-4, np.inf)
        src.pose(t - 0.1, _Nav())
        src.images(t - 0.05, np.zeros((8, 8), np.uint8), np.zeros((8, 8), np.uint8))
        src.map(t, emap)
    rec.close()
    new = int((ahead | behind).sum())
    steps = [{"step": 0, "view": "panorama", "expected_new_cells": 0.0, "view_new_cells": 10},
             {"step": 1, "view": "5", "expected_new_cells": 500.0, "view_new_cells": new}]
    (tmp_path / "run" / "summary.json").write_text(json.dumps({"steps": steps}))
    (v,) = decompose_run(tmp_path / "run", spec, 0, what_if={"wide": {"prior_corr_len_m": 4.0}})
    assert v.step == 1 and v.obtained == new and v.outside_fov == int(behind.sum())
    assert v.ideal > 0 and v.pv_sum > 0 and v.obtained_ideal <= min(v.ideal, v.obtained)
    assert v.what_if["wide"] >= v.pv_sum  # a longer correlation: fewer unknown occluders, P_V no lower
    assert "| stereo return: obtained / cells the truth leaves visible |" in split_table([v], 0.8)
    (tmp_path / "run" / "mission.mcap").write_bytes(b"\x89MCAP0\r\n" + bytes(40))  # a recording cut short
    with pytest.raises(ValueError, match="unreadable recording"):
        decompose_run(tmp_path / "run", spec, 0)


def test_the_table_reports_the_parts_and_a_bad_key_is_refused() -> None:
    views = [ViewSplit(k, 100.0, 120, 125.0, 100, 90, 0, 5, 0) for k in range(4)]
    md = split_table(views, 0.8)
    assert "| obtained / expected (the planner's, at the pose it rated) | 1.20 (1.20-1.20) |" in md
    assert "| occlusion model: sum P_V / cells the truth leaves visible | 1.25 (1.25-1.25) |" in md
    from hil_sim.lab.prediction_check import what_if_values

    assert what_if_values(["prior_corr_len_m=2"]) == {"prior_corr_len_m=2": {"prior_corr_len_m": 2.0}}
    with pytest.raises(ValueError, match="not KEY=VALUE"):
        what_if_values(["no_such_key=1"])


def test_the_command_finds_mission_directories_and_refuses_none(tmp_path, capsys) -> None:
    from hil_sim.cli import main
    from hil_sim.lab.prediction_check import mission_dirs

    for name in ("a", "b"):
        (tmp_path / "runs" / name).mkdir(parents=True)
        (tmp_path / "runs" / name / "summary.json").write_text("{}")
    (tmp_path / "runs" / "unfinished").mkdir()
    assert [d.name for d in mission_dirs([tmp_path / "runs"])] == ["a", "b"]
    assert mission_dirs([tmp_path / "runs" / "a"]) == [tmp_path / "runs" / "a"]
    assert main(["experiment", "prediction", str(tmp_path / "runs" / "unfinished")]) == 2
    assert main(["experiment", "prediction", str(tmp_path), "--what-if", "nope=1"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 2
