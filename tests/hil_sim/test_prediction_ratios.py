"""Expected against obtained new cells per step (issue 30 item 3): only the views the planner
rated count; looks and refused moves (no prediction, expected 0) are reported apart."""

from __future__ import annotations

import pytest

from hil_sim.mission.mission_report import prediction_ratios


def _step(i: int, view: str, exp: float, got: int, view_got: int | None = None) -> dict:
    return {"step": i, "view": view, "expected_new_cells": exp, "obtained_new_cells": got,
            "view_new_cells": got if view_got is None else view_got}


def test_rated_views_only_and_their_own_cells() -> None:
    steps = [_step(0, "panorama", 0.0, 7000),
             _step(1, "5", 1000.0, 1100),
             _step(2, "look", 0.0, 4800),  # no prediction: apart, not a ratio of infinity
             _step(3, "5", 2000.0, 2500, view_got=1600),  # a look before it in the step: its own cells
             _step(4, "part-way", 900.0, 3000),  # the rated pose not reached
             _step(5, "5", 500.0, 250),
             _step(6, "stay", 0.0, 10)]
    r = prediction_ratios(steps)
    assert r["rated_steps"] == 3 and r["unrated_steps"] == 3
    assert r["unrated_new_cells"] == 4800 + 3000 + 10
    assert r["median_ratio"] == pytest.approx(0.8)  # of 1.1, 0.8, 0.5
    assert r["p10_ratio"] == pytest.approx(0.56) and r["p90_ratio"] == pytest.approx(1.04)


def test_no_rated_view_gives_no_ratio() -> None:
    r = prediction_ratios([_step(0, "panorama", 0.0, 7000), _step(1, "look", 0.0, 50)])
    assert r["rated_steps"] == 0 and "median_ratio" not in r
    # summaries written before the view was recorded: nothing is taken for rated
    assert prediction_ratios([{"step": 1, "expected_new_cells": 10.0, "obtained_new_cells": 30}])["rated_steps"] == 0
