"""The team mission's judge (hil_sim.team.team_eval): each figure computed from the truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

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


def _face_with_a_rock() -> tuple[np.ndarray, MapGrid]:
    """A 70 deg face below a lip, a rock on the face beside the Cliff-bot's ways."""
    grid = MapGrid(-1.8, -1.6, 0.03, 120, 110)
    gx, gy = grid.centers()
    z = np.where(gy > 0, 0.0, math.tan(math.radians(70.0)) * gy)
    z[np.hypot(gx + 0.4, gy + 0.3) < 0.08] += 0.6
    return z.astype(np.float64), grid


@pytest.mark.slow
def test_the_truths_settle_memo_gives_settles_answers_and_works_each_out_once(monkeypatch) -> None:
    """The ways judged through the memo (the truth's brute force) get the verdicts of the ways
    judged with ``settle`` itself, at the exact lengths and under the winches' tolerance; the
    second judging of the same ways settles nothing again; another ground is not answered from it."""
    from fsw.core.team import tether, tether_settle
    from fsw.core.team.climber_ground import ClimberConfig, ground_layers
    from fsw.core.team.face_planner import way_reason
    from hil_sim.team import team_eval

    z, grid = _face_with_a_rock()
    t, c = tether.TetherConfig(), ClimberConfig()
    anchors = tether.anchor_points(z, grid, np.array([[-1.5, 1.5], [1.5, 1.5]]), t)
    g = ground_layers(z, grid, c)
    calls: list[tuple[float, float]] = []

    def counted(*args, **kw):
        calls.append(args[3])
        return tether_settle.settle(*args, **kw)

    monkeypatch.setattr(team_eval, "settle", counted)
    memo = team_eval._SettleMemo(z, grid, anchors, t)
    ways = [(np.array([x, -0.78]), np.array([x + dx, -0.84])) for x in (-0.06, 0.2) for dx in (-0.06, 0.0)]
    ways += [(b, a) for a, b in ways]
    tol = team_eval.winch_errors(0.01, 2.326)
    for errors in (None, tol):
        plain = [way_reason(z, grid, anchors, a, b, t, c, g, errors=errors) for a, b in ways]
        memo_got = [way_reason(z, grid, anchors, a, b, t, c, g, errors=errors, settle_at=memo) for a, b in ways]
        assert memo_got == plain
        if errors is None:
            first = len(calls)
            assert first > len(ways) and len(set(plain)) > 1, plain  # the ways settled, and not all alike
    assert len(calls) == first  # under the tolerance every way's steps were settled at the exact lengths
    for key, got in list(memo._got.items())[:20]:  # each kept answer is settle's own, bit for bit
        again = tether_settle.settle(z, grid, anchors, key[:2], np.array(key[2:]), t)
        assert (got is None) == (again is None)
        if got is not None and again is not None:
            assert got[0].tobytes() == again[0].tobytes() and got[1].lengths_m == again[1].lengths_m
    other = z.copy()
    other[np.hypot(*grid.centers()) < 0.5] -= 0.05  # another ground: settled on it, not answered from the memo
    a, b = ways[0]
    assert way_reason(other, grid, anchors, a, b, t, c, g, settle_at=memo) == way_reason(other, grid, anchors, a, b,
                                                                                         t, c, g)
    assert len(calls) > first
