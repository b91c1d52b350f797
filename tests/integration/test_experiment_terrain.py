"""``safer-hil experiment terrain`` and its metrics (issue 13): tilted ``file:`` DEMs, the
fitted map tilt, station seams, and the command's usage errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from fsw.core.geometry import MapGrid
from hil_sim.lab.experiments.experiment_terrain import tilted_spec
from hil_sim.lab.terrain_eval import plane_tilt_deg, seams, stations

GRID = MapGrid(0.0, 0.0, 0.05, 40, 30)


def test_plane_tilt_of_a_tilted_error_map() -> None:
    X, Y = GRID.centers()
    err = math.tan(math.radians(0.3)) * (0.6 * X + 0.8 * Y) + 0.01
    mask = np.ones(GRID.shape, bool)
    assert plane_tilt_deg(GRID, err, mask) == pytest.approx(0.3, abs=1e-9)
    assert math.isnan(plane_tilt_deg(GRID, err, np.zeros(GRID.shape, bool)))


def test_seams_between_stations_not_between_views_of_one_station() -> None:
    n = GRID.nx * GRID.ny
    idx = np.arange(0, 400, dtype=np.int32)
    z = np.zeros(400, np.float32)
    views = [((0.0, 0.0, 1.5), idx, z), ((0.01, 0.0, 1.5), idx, z + 0.05),  # one station, two views
             ((1.0, 0.0, 1.5), idx[100:], z[100:] + 0.012)]  # another station, 300 shared cells
    assert stations([v[0] for v in views]) == [0, 0, 1]
    out = seams(views, n)
    assert out["stations"] == 2 and out["pairs"] == 1
    assert out["seam_m"] == pytest.approx(0.025 - 0.012, abs=1e-6)  # station 0: mean of its two views
    assert seams(views[:2], n)["seam_m"] is None  # a single station has no seam


def test_tilted_spec_adds_the_asked_slope(tmp_path: Path) -> None:
    from hil_sim.world import load_scenario

    flat = load_scenario("lab", seed=0)
    spec = tilted_spec("lab", 0, 8.0, 0.0, tmp_path)  # falls toward +x
    w = load_scenario(spec, seed=0)
    x0, y0, _ = w.rover_start
    assert float(w.ground_at(x0, y0)) == pytest.approx(0.0, abs=1e-3)
    d_flat = float(flat.ground_at(x0 + 1.0, y0) - flat.ground_at(x0, y0))
    d_tilt = float(w.ground_at(x0 + 1.0, y0) - w.ground_at(x0, y0))
    assert d_tilt - d_flat == pytest.approx(-math.tan(math.radians(8.0)), abs=2e-3)


@pytest.mark.parametrize("args", [["--slopes", "abc"], ["--slopes", "45"], ["--seeds", ""],
                                  ["--scenario", "nosuch"], ["--scenario", "file:/nonexistent.npy"]])
def test_usage_errors_exit_2_with_one_line(args: list[str], tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """The command's own entry (``safer-hil`` runs ``hil_sim.cli.main``), in this process: an
    exception would fail the test; argparse's own refusals exit through SystemExit."""
    from hil_sim.cli import main

    try:
        code = main(["experiment", "terrain", *args, "--out", str(tmp_path)])
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
