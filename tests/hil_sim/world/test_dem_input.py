"""DEM input (issue 13 item 4): bad files get one clear line; a real DEM works through file:.

Requirements: heights beyond the sane range, non-finite heights and a file that is not the
type its name says are refused with a one-line ScenarioError (and exit 2 at the CLI); the DEM
is zeroed at the rover start; a sloped DEM keeps its plateau (slope-connected), and the real
Jacksboro DEM (matplotlib sample data) builds a world with an edge and a tilted start.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from fsw.settings import load_settings
from hil_sim.cli import main
from hil_sim.rover_truth import RoverTruth, RoverTruthConfig
from hil_sim.world import ScenarioError, load_scenario
from hil_sim.world.sample_dem import jacksboro_dem


def _step_dem(drop_m: float = 0.5, slope_deg: float = 0.0) -> np.ndarray:
    y = np.arange(700)[:, None] * 0.01 - 6.0 + 0.005
    x = np.arange(700)[None, :] * 0.01 - 1.0 + 0.005
    z = math.tan(math.radians(slope_deg)) * x + np.where(y > -1.0, 0.0, -drop_m)
    return np.asarray(z + 0.0 * y, np.float32)


@pytest.mark.parametrize("name, content, why", [
    ("text.npy", b"just some text, not an array\n", "not a NumPy .npy file"),
    ("png.npy", b"\x89PNG\r\n\x1a\n" + bytes(64), "not a NumPy .npy file"),
    ("text.png", b"P5 not a png", "not a PNG file"),
    ("empty.npy", b"", "not a NumPy .npy file"),
])
def test_file_not_of_its_type_is_refused(tmp_path, name, content, why):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(ScenarioError, match=why) as err:
        load_scenario(f"file:{path}")
    assert "\n" not in str(err.value) and "pickle" not in str(err.value).lower()


def test_pickled_npy_is_refused_without_numpy_message(tmp_path):
    path = tmp_path / "objects.npy"
    np.save(path, np.array([{"a": 1}, None], dtype=object), allow_pickle=True)
    with pytest.raises(ScenarioError, match="Python objects"):
        load_scenario(f"file:{path}")


@pytest.mark.parametrize("value, why", [
    (1e30, "beyond the sane range"),
    (-2000.0, "beyond the sane range"),
    (np.inf, "NaN or infinite"),
    (np.nan, "NaN or infinite"),
])
def test_insane_heights_are_refused(tmp_path, value, why):
    dem = _step_dem()
    dem64 = dem.astype(np.float64)
    dem64[10, 10] = value
    np.save(tmp_path / "bad.npy", dem64)
    with pytest.raises(ScenarioError, match=why):
        load_scenario(f"file:{tmp_path / 'bad.npy'}")


def test_height_range_is_configurable(tmp_path):
    dem = _step_dem() + np.float32(1500.0)  # a real site 1.5 km above the datum
    np.save(tmp_path / "high.npy", dem)
    with pytest.raises(ScenarioError, match="1000"):
        load_scenario(f"file:{tmp_path / 'high.npy'}")
    w = load_scenario(f"file:{tmp_path / 'high.npy'}?max_abs_height_m=5000")
    assert w.ground_at(0.0, 0.0) == pytest.approx(0.0, abs=1e-3)  # zeroed at the start
    assert w.plateau_z == pytest.approx(0.0, abs=1e-3)


def test_bad_dem_exits_2_with_one_line(tmp_path, capsys):
    path = tmp_path / "dem.npy"
    path.write_text("1 2 3\n4 5 6\n")
    rc = main(["run", "--scenario", f"file:{path}", "--steps", "1", "--out", str(tmp_path / "o")])
    cap = capsys.readouterr()
    err = cap.err.strip().splitlines()[-1:]  # the progress bar is closed first
    err = "\n".join(line.split("\r")[-1] for line in err)
    assert rc == 2 and len(err.splitlines()) == 1 and "not a NumPy .npy file" in err


def test_sloped_dem_plateau_follows_the_slope(tmp_path):
    """On a 6 deg regional slope the plateau is the ground connected to the start without a
    steep step: the whole upper side, not a band within a height tolerance of the start."""
    np.save(tmp_path / "slope.npy", _step_dem(drop_m=0.8, slope_deg=6.0))
    w = load_scenario(f"file:{tmp_path / 'slope.npy'}")
    ys = w.y0 + (np.arange(w.shape[0]) + 0.5) * w.cell_m
    upper = ys > -0.95
    assert w.plateau[upper].mean() > 0.98 and w.plateau[ys < -1.05].mean() < 0.02
    assert np.allclose(w.edge_xy[:, 1], -1.0, atol=0.03)
    # Driving downhill on the plateau is not over the drop; past the edge it is.
    assert not w.over_drop(np.array([4.0]), np.array([0.5]), 0.1).any()
    assert w.over_drop(np.array([2.0]), np.array([-2.0]), 0.1).all()


def test_real_dem_through_file_scenario(tmp_path):
    """matplotlib's Jacksboro DEM at rover scale with a drop: a world whose rover starts
    tilted on the plateau, with the edge where the drop was added."""
    np.save(tmp_path / "jacksboro.npy", jacksboro_dem(0.03, drop_m=1.0, edge_y_m=-1.0))
    w = load_scenario(f"file:{tmp_path / 'jacksboro.npy'}?cell_m=0.03")
    assert w.ground_at(0.0, 0.0) == pytest.approx(0.0, abs=2e-3)
    assert len(w.edge_xy) > 100 and np.median(np.abs(w.edge_xy[:, 1] + 1.0)) < 0.05
    r = RoverTruth(w, load_settings().rover, RoverTruthConfig(), 0, w.rover_start)
    assert math.hypot(r.pitch, r.roll) > math.radians(0.5)  # the start is not level
    assert not r.wheels_off.any()


def test_png_dem_is_checked_too(tmp_path):
    counts = np.full((700, 700), 40000, np.uint16)
    cv2.imwrite(str(tmp_path / "big.png"), counts)
    with pytest.raises(ScenarioError, match="sane range"):
        load_scenario(f"file:{tmp_path / 'big.png'}?z_scale_m=1.0")


def test_start_without_room_for_the_wheels_is_refused(tmp_path):
    np.save(tmp_path / "edge.npy", np.zeros((100, 700), np.float32))  # y -6 .. -5
    with pytest.raises(ScenarioError, match="outside the DEM|no room for its wheels"):
        load_scenario(f"file:{tmp_path / 'edge.npy'}")
    np.save(tmp_path / "tight.npy", np.zeros((630, 700), np.float32))  # y -6 .. 0.3
    with pytest.raises(ScenarioError, match="no room for its wheels"):
        load_scenario(f"file:{tmp_path / 'tight.npy'}")


@pytest.mark.parametrize("shape, why", [
    ((99_999, 99_999), "header claims shape"),  # 37 GiB of float32 if allocated
    ((700, 700), "header needs"),  # a plausible header on a file cut short
])
def test_npy_header_is_checked_before_allocation(tmp_path, shape, why):
    """req(26.6): the .npy header's size is checked against the limit and the file's length
    before NumPy allocates anything: one line, no MemoryError."""
    path = tmp_path / "hostile.npy"
    with path.open("wb") as fh:
        np.lib.format.write_array_header_1_0(fh, {"descr": "<f4", "fortran_order": False, "shape": shape})
        fh.write(bytes(4096))
    with pytest.raises(ScenarioError, match=why) as err:
        load_scenario(f"file:{path}")
    assert "\n" not in str(err.value)


def test_png_header_is_checked_before_decoding(tmp_path):
    """req(26.6): a PNG whose IHDR claims 100,000 x 100,000 pixels is refused from its header."""
    path = tmp_path / "hostile.png"
    ihdr = (100_000).to_bytes(4, "big") * 2 + bytes([16, 0, 0, 0, 0])
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + len(ihdr).to_bytes(4, "big") + b"IHDR" + ihdr + bytes(4))
    with pytest.raises(ScenarioError, match="PNG header claims 100000 x 100000"):
        load_scenario(f"file:{path}")
