"""A start placed beside a scenario's own edge (issue 30 item 1: close-edge starts on a real DEM).

Requirements: ``start_near_edge`` puts the footprint the asked distance from the true edge with
the edge at the asked bearing (ahead, diagonal, right), on the plateau; the flight map of a DEM
is laid in the start's frame (odometry), so a turned start's map still covers the DEM; a world
without an edge is refused with one line.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fsw.core.geometry import MapGrid
from hil_sim.world import ScenarioError, load_scenario
from hil_sim.world.scenarios import footprint_gap, start_near_edge


def _step_dem(path, drop_m: float = 0.5) -> str:
    """A 4 m x 4 m DEM at 2 cm (corner at (-1, -3)) with the plateau above y = -1 m."""
    y = np.arange(200)[:, None] * 0.02 - 3.0 + 0.01
    z = np.where(y > -1.0, 0.0, -drop_m) + np.zeros((1, 200))
    np.save(path, z.astype(np.float32))
    return f"file:{path}?cell_m=0.02&x_min_m=-1&y_min_m=-3&cliffbot.x_m=1.5&cliffbot.y_m=-2.2"


@pytest.mark.parametrize("bearing", [0.0, -45.0, -90.0])
def test_the_start_is_placed_the_asked_gap_from_the_edge_at_the_asked_bearing(tmp_path, bearing):
    base = _step_dem(tmp_path / "step.npy")
    spec, gap = start_near_edge(base, bearing, 0.3)
    w = load_scenario(spec, 0)
    x, y, yaw = w.rover_start
    assert gap == pytest.approx(0.3, abs=0.01)
    assert footprint_gap(np.asarray(w.edge_xy), x, y, yaw) == pytest.approx(0.3, abs=0.015)
    # the edge runs along x at y = -1 with the drop toward -y: it lies at the bearing from the heading
    toward_edge = math.degrees(math.atan2(-1.0, 0.0) - yaw)
    assert (toward_edge - bearing + 180) % 360 - 180 == pytest.approx(0.0, abs=3.0)
    assert w.on_plateau(x, y) and y > -1.0


def test_a_turned_start_lays_the_map_in_its_own_frame_over_the_dem(tmp_path):
    spec, _ = start_near_edge(_step_dem(tmp_path / "step.npy"), 0.0, 0.3)
    w = load_scenario(spec, 0)
    grid = MapGrid.from_config(w.map_grid)
    truth = w.truth_on_grid(grid, w.rover_start)  # NaN where a map cell is off the DEM
    assert np.isfinite(truth).mean() > 0.5
    plain = load_scenario(_step_dem(tmp_path / "plain.npy"), 0)  # start at the origin: the DEM as it is
    assert (plain.map_grid.origin_x_m, plain.map_grid.origin_y_m) == (-1.0, -3.0)


def test_a_world_without_an_edge_is_refused(tmp_path):
    path = tmp_path / "flat.npy"
    np.save(path, np.zeros((200, 200), np.float32))
    with pytest.raises(ScenarioError, match="no edge") as err:
        start_near_edge(f"file:{path}?cell_m=0.02&x_min_m=-1&y_min_m=-3&cliffbot.x_m=1.5&cliffbot.y_m=-2.2", 0.0, 0.3)
    assert "\n" not in str(err.value)


def test_wheels_on_unknown_ground_are_judged_in_the_flight_map_frame() -> None:
    """A start away from the world's origin (a start placed beside a DEM's edge): the true wheels
    are taken into the odometry's frame before the flight's known ground is asked."""
    from types import SimpleNamespace

    from hil_sim.mission.ground_watch import wheels_on_unknown

    known_box = SimpleNamespace(known_xy=lambda p: (np.abs(p[:, 0]) < 1.0) & (np.abs(p[:, 1]) < 1.0))
    mission = SimpleNamespace(ground=SimpleNamespace(geofence=SimpleNamespace(known=known_box)))
    wheels = (np.array([5.3, 5.3, 4.7, 4.7]), np.array([-2.3, -1.7, -2.3, -1.7]))  # around (5, -2) in the world

    def rig(start: tuple[float, float, float]) -> SimpleNamespace:
        rover = SimpleNamespace(odometer_m=1.0, world_wheel_xy=lambda: wheels)
        return SimpleNamespace(rover=rover, world=SimpleNamespace(rover_start=start))

    assert wheels_on_unknown(rig((5.0, -2.0, math.radians(90.0))), mission, 0.5) == 0  # the map's origin
    assert wheels_on_unknown(rig((0.0, 0.0, 0.0)), mission, 0.5) == 1  # 5 m from the known box
    assert wheels_on_unknown(rig((5.0, -2.0, 0.0)), mission, 1.0) == 0  # did not move
