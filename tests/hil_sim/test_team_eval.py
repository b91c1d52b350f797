"""The team mission's judge (hil_sim.team.team_eval): each figure computed from the truth."""

from __future__ import annotations

import math

import numpy as np

from fsw.core.geometry import MapGrid
from hil_sim.team.team_eval import (
    CHI2_95_6DOF,
    FixError,
    TeamOutcome,
    TeamVerdict,
    fix_error,
    path_length_m,
    unknown_at_entry,
    unknown_cells_entered,
)

GRID = MapGrid(0.0, 0.0, 0.1, 10, 10)


def test_unknown_cells_counts_distinct_cells_after_the_start() -> None:
    z = np.zeros((10, 10))
    z[5, 6:8] = np.nan
    path = [(0.55, 0.55), (0.55, 0.55), (0.56, 0.54), (0.65, 0.55), (0.66, 0.56), (0.25, 0.25)]
    # the start (5, 5) is not counted; (5, 6) is entered twice: one cell
    assert unknown_cells_entered(path[:1], z, GRID) == 0
    assert unknown_cells_entered(path, z, GRID) == 1
    assert unknown_cells_entered([(0.25, 0.25), (5.0, 5.0)], z, GRID) == 1  # off the map is unknown


def test_a_cell_is_judged_against_the_map_held_when_it_was_entered() -> None:
    """A cell the Cliff-bot drove onto unknown and whose ground its camera showed later counts:
    the final map knows it, the map it held then did not (nor does the plane carried under its
    body, which the bench leaves out of ``known``)."""
    then = np.ones((10, 10), bool)
    then[5, 6] = False
    final = np.zeros((10, 10))  # the final map knows every cell
    step = np.array([[0.65, 0.55]])
    assert unknown_cells_entered([(0.55, 0.55), (0.65, 0.55)], final, GRID) == 0
    assert unknown_at_entry(step, then, GRID) == {(5, 6)}
    assert unknown_at_entry(np.array([[0.55, 0.55]]), then, GRID) == set()
    assert unknown_at_entry(step, None, GRID) == {(5, 6)}  # no map yet: nothing known
    assert unknown_at_entry(np.array([[5.0, 5.0]]), then, GRID) == {(50, 50)}  # off the map


def test_fix_error_nees_follows_the_covariance() -> None:
    cov = np.diag([1e-4] * 3 + [1e-4] * 3)
    f = fix_error(np.array([1.02, 0.0, 0.0]), np.zeros(3), math.radians(-2.0), cov, np.array([1.0, 0.0, 0.0]), 4.0)
    assert math.isclose(f.err_cm, 2.0, rel_tol=1e-9) and math.isclose(f.err_deg, 2.0)
    assert math.isclose(f.nees, 0.02 ** 2 / 1e-4) and f.range_m == 4.0
    assert fix_error(np.zeros(3), np.zeros(3), 0.0, np.zeros((6, 6)), np.ones(3)).nees == math.inf


def test_verdict_names_reachable_targets_missed() -> None:
    o = TeamOutcome(reached=(True, False, False), map_reasons=("", "no safe path", "hazard"),
                    true_path=((0.0, 0.0), (3.0, 4.0)), violations={"tension": 2, "slack": 0},
                    hazard_cells=frozenset({(1, 1)}),
                    fixes=(FixError(3.0, 1.0, 0.2, 2.0), FixError(6.0, 3.0, 0.5, CHI2_95_6DOF + 1)))
    v = TeamVerdict(o, ("", "", "hazard"), 0)
    s = v.section()
    assert v.missed == [1] and s["reachable_missed"] == [1]
    assert s["targets_reachable_by_truth"] == 2 and s["targets_unreachable_by_truth"] == 1
    assert s["tether_violations"] == 2 and s["hazard_cells_entered"] == 1
    assert s["fix_nees_within_chi2_95"] == 0.5 and s["path_m"] == 5.0 == path_length_m(o.true_path)
