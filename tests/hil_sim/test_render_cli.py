"""``safer-hil render`` and ``safer-hil bench render``.

Requirement: issue 3 "Done when": ``safer-hil render --scenario lab --out DIR`` writes a
left/right PNG pair and a truth elevation PNG; ``safer-hil bench render`` prints the time
per stereo pair at 320x240 and 640x480. CLI standard: exit 2 on bad arguments or input.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from hil_sim.cli import main


def test_render_writes_pair_truth_and_record(tmp_path, capsys):
    out = tmp_path / "out"
    rc = main(["render", "--scenario", "lab", "--out", str(out), "--size", "160,120",
               "--noise", "1.5"])
    assert rc == 0
    left = cv2.imread(str(out / "left.png"), cv2.IMREAD_UNCHANGED)
    right = cv2.imread(str(out / "right.png"), cv2.IMREAD_UNCHANGED)
    assert left.shape == right.shape == (120, 160) and left.dtype == np.uint8
    assert not np.array_equal(left, right)
    truth = cv2.imread(str(out / "truth_elevation.png"))
    assert truth is not None and truth.shape[0] > 300
    assert np.load(out / "truth_elevation.npy").shape == (1100, 1100)
    depth = np.load(out / "depth.npy")
    assert depth.shape == (120, 160) and np.isfinite(depth).any()
    record = json.loads((out / "render.json").read_text())
    assert record["world"] == "lab" and record["noise_sigma"] == 1.5
    assert set(record["cliffbot"]["marker_corners_world"]) == {"1", "2", "3", "4"}
    assert "pair written" in capsys.readouterr().out


def test_render_with_a_png_dem_and_explicit_pose(tmp_path):
    counts = np.full((400, 500), 1000, np.uint16)
    counts[250:, :] = 600  # a 0.4 m step (1 mm per count), north up
    cv2.imwrite(str(tmp_path / "site.png"), counts)
    rc = main(["render", "--scenario", f"file:{tmp_path / 'site.png'}?y_min_m=-3&x_min_m=-1",
               "--dem-scale", "0.001", "--out", str(tmp_path / "o"), "--size", "96,72",
               "--rover", "0.5,0.5,0", "--mast=-80,-40,0.2", "--seed", "3"])
    assert rc == 0
    record = json.loads((tmp_path / "o" / "render.json").read_text())
    assert record["seed"] == 3 and record["rover_xy_yaw"] == [0.5, 0.5, 0.0]


@pytest.mark.parametrize("argv, code", [
    (["render", "--scenario", "moon", "--out", "X"], 2),
    (["render", "--scenario", "lab?drop_m=2", "--out", "X"], 2),
    (["render", "--scenario", "file:/no/such.npy", "--out", "X"], 2),
    (["render", "--scenario", "lab", "--out", "X", "--noise", "-1"], 2),
])
def test_render_bad_input_exits_2(tmp_path, argv, code, capsys):
    argv = [a.replace("X", str(tmp_path / "x")) for a in argv]
    assert main(argv) == code
    assert "safer-hil render:" in capsys.readouterr().out


@pytest.mark.parametrize("argv", [
    ["render", "--out", "x", "--mast", "1,2"],
    ["render", "--out", "x", "--rover", "a,b,c"],
    ["render"],
    ["bench", "render", "--sizes", "640by480"],
])
def test_usage_errors_exit_2(argv):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2


def test_bench_render_prints_figures(capsys):
    rc = main(["bench", "render", "--sizes", "64x48", "96x72", "--repeats", "1"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "median s/pair" in out and "64x48" in out and "96x72" in out
