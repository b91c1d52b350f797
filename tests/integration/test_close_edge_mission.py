"""A mission with the edge close to the start moves, safely (issue 13 item 3).

The generated terrain puts the edge 0.3 m from the rover's right wheels (the closest the
generator draws): before issue 13 the rover never left the start on such ground. Now it looks
at the ground it would cross, moves, never puts a wheel over the drop, off the world or on
ground the flight software has not mapped, and uses all its steps (two imaging steps, as
``safer-hil experiment close-edge`` runs each start: the rover moves well beyond 0.3 m in them).
"""

from __future__ import annotations

import pytest

from hil_sim.mission.mission_run import RunSpec, run_mission

pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]  # a lockstep mission each: minutes on a loaded machine


def test_close_edge_mission_moves_safely():
    s = run_mission(RunSpec("terrain?edge_distance_m=0.3&slope_deg=4", "5", steps=2, seed=1,
                            transmit=False))
    assert s["odometer_m"] > 0.3, s["stays"]
    assert s["edge_violations"] == 0
    assert s["wheels_off_terrain"] == 0 and s["bench_faults"] == []
    assert s["wheels_on_unknown_ground"] == 0
    assert len(s["steps"]) - 1 == 2 and s["steps_unused"] == 0 and s["final_state"] == "DONE"
    assert s["looks"] >= 1  # it looked at unmapped ground before driving over it


def test_rover_off_the_edge_path_moves_at_its_first_step():
    """Drawn terrain 10 (5 deg slope, edge 0.64 m from the wheels, irregular): the fitted edge
    comes in pieces, and the plateau beside the drop was a separate contour from the largest
    one, so a piece's straight continuation ran across mapped plateau past the rover and no
    station was reachable; the rover stood still for every step. Now every plateau piece
    clips the continuation, and a rover off the edge path also has stations straight ahead
    and behind (no turn in place): it moves at its first step, safely. Its wheels keep the
    geofence's margin from ground the map has not measured (a hidden lip may lie there), so that
    first move is a short part-way one."""
    s = run_mission(RunSpec("terrain?slope_deg=-1", "5", steps=1, seed=10, transmit=False))
    assert s["reachable_stations"][1] > 0
    assert s["odometer_m"] > 0.1, s["stays"]
    assert s["edge_violations"] == 0 and s["wheels_off_terrain"] == 0
    assert s["wheels_on_unknown_ground"] == 0
    assert s["steps_unused"] == 0 and s["final_state"] == "DONE"


def test_rover_facing_a_close_edge_backs_off_at_its_first_step():
    """Issue 30 item 1: the edge 0.3 m ahead of the bumper (``edge_bearing_deg=0``): the rover
    stands on the edge path facing the drop and the turn toward the path is refused, so before
    it never left the start (nor did Method 1). Now its first step is an escape move (straight
    back or a turn in place), safely."""
    s = run_mission(RunSpec("terrain?edge_bearing_deg=0&edge_distance_m=0.3", "5", steps=1, seed=0,
                            transmit=False))
    assert s["reachable_stations"][1] > 0
    assert s["odometer_m"] > 0.1, s["stays"]
    assert s["edge_violations"] == 0 and s["wheels_off_terrain"] == 0
    assert s["wheels_on_unknown_ground"] == 0
    assert s["steps_unused"] == 0 and s["final_state"] == "DONE"
