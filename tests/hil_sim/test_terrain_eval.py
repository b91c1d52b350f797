"""The map-quality figures against the truth in the flight map's datum (``hil_sim.lab.terrain_eval``):
the datum is the true body height at the start, which on rocky ground is not the ground under
the rover's centre (docs/perception.md, "Map datum")."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hil_helpers import cfg

from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap
from hil_sim.lab.terrain_eval import map_quality
from hil_sim.rover_truth import RoverTruth, RoverTruthConfig

GRID = MapGrid(0.0, 0.0, 0.03, 60, 50)
EXACT = RoverTruthConfig(slip_mean=0.0, slip_bias_sigma=0.0, slip_noise_sigma=0.0, steer_offset_sigma_deg=0.0)


def _map(truth: np.ndarray, err: np.ndarray, sigma: float) -> ElevationMap:
    emap = ElevationMap(GRID)
    emap.z, emap.var = truth + err, np.full(GRID.shape, sigma**2)
    emap.n[:] = 1
    return emap


def test_figures_are_taken_in_the_flight_datum_and_kept_in_the_ground_datum() -> None:
    rng = np.random.default_rng(4)
    X, Y = GRID.centers()
    truth = 0.05 * np.sin(3 * X) + 0.1 * Y
    datum, sigma = 0.018, 0.005
    noise = rng.normal(0.0, sigma, GRID.shape)
    q = map_quality(_map(truth, noise - datum, sigma), truth, [], datum_m=datum)  # the map sits on the body
    assert q["datum_m"] == datum
    assert q["rms_m"] == pytest.approx(float(np.sqrt(np.mean(noise**2))), rel=1e-9)
    assert 0.93 < q["within_2sigma"] < 0.97  # Gaussian errors at their sigma
    assert q["tilt_err_deg"] < 0.05
    # the same map against the ground under the rover's centre: a 3.6-sigma offset everywhere
    assert q["rms_ground_datum_m"] == pytest.approx(math.hypot(datum, q["rms_m"]), rel=0.02)
    assert q["within_2sigma_ground_datum"] < 0.1
    q0 = map_quality(_map(truth, noise - datum, sigma), truth, [])  # no datum: the old figures
    assert q0["within_2sigma"] == q0["within_2sigma_ground_datum"] == q["within_2sigma_ground_datum"]
    with pytest.raises(ValueError, match="datum_m"):
        map_quality(_map(truth, noise, sigma), truth, [], datum_m=math.nan)


class _Bowl:
    """Ground rising away from the origin: the centre sits in a dip below the four wheels."""

    def height_at(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        return np.asarray(0.2 * (np.square(x) + np.square(y)), dtype=float)


def test_the_true_body_rests_on_its_wheels_not_on_the_ground_under_its_centre() -> None:
    """What ``datum_m`` is: the bench body's height at the start, the mean of the four contact
    heights, here well above the ground under its centre (0)."""
    rover = RoverTruth(_Bowl(), cfg().rover, EXACT, 0)
    wx, wy = rover.world_wheel_xy()
    contacts = _Bowl().height_at(wx, wy)
    assert rover.z == pytest.approx(float(np.mean(contacts)), abs=1e-9)
    assert rover.z > 0.01  # a 1 cm-scale datum difference on a bowl of 0.2 / m
