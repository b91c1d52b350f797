"""The fiducials experiment's placements (hil_sim/lab/experiments/experiment_fiducials.py): each fix
comes from the flight localizer with the attitude the Cliff-bot's sensor would send, and no fix is
a mirror pose."""

from __future__ import annotations

import math

import pytest

from hil_sim.lab.experiments.experiment_fiducials import _sensed_attitude, range_rows

SCENE = "cliff-team?face_slope_deg=60&drop_m=3"


def test_the_sensed_attitude_of_a_level_body_is_the_sensors_noise() -> None:
    import numpy as np

    from hil_sim.team.cliffbot_rig import CliffbotHw

    draws = np.degrees([_sensed_attitude(np.random.default_rng([0, 57, k])) for k in range(400)])
    assert abs(float(draws.mean())) < 0.05 and float(draws.std()) == pytest.approx(CliffbotHw().imu_noise_deg, rel=0.15)


@pytest.mark.slow
def test_far_placements_give_fixes_with_their_attitude_and_none_is_a_mirror() -> None:
    rows = range_rows(SCENE, 0, "config/fsw.toml", 0, 5.0, 4)
    assert len(rows) == 4
    fixes = [r for r in rows if r["fix"]]
    assert fixes, rows
    for r in fixes:  # a mirror pose stands tens of degrees off; the pose's own error is a fraction of one
        assert r["yaw_err_deg"] < 3.0 and r["pos_err_cm"] < 5.0 and math.isfinite(r["nees"]), r
