"""Both agents' views into the face map on the bench (``hil_sim.team.face_scene``,
``safer-hil experiment face-map``; docs/algorithm.md §8.1): a tiny seeded scene."""

from __future__ import annotations

import pytest

from hil_sim.cli import main
from hil_sim.team.face_scene import FaceScene


@pytest.mark.parametrize("argv", [
    ["experiment", "face-map", "--scenes", "0"],
    ["experiment", "face-map", "--jobs", "0"],
    ["experiment", "face-map", "--scenes", "1", "--scenario", "nowhere"],
])
def test_bad_input_exits_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(argv) == 2
    assert "Traceback" not in capsys.readouterr().err


@pytest.mark.slow
def test_the_team_is_masked_and_the_judge_sees_it_without() -> None:
    """A view from the Cliff-bot on the face with its own body, the tethers, the RECON-bot and
    the Anchorbots in the picture: masked, no point on them (judged on the truth) reaches the
    map and no cell of them is mapped; unmasked, the same view fuses such points."""
    row = FaceScene("cliff-team", 3, "config/fsw.toml").measure(0, 1)
    assert row["views"] == 1 and row["team_points_seen"] >= 10
    assert row["team_points_fused"] == 0 and row["team_cells_mapped"] == 0
    bare = FaceScene("cliff-team", 3, "config/fsw.toml", mask=False).measure(0, 1)
    assert bare["team_points_seen"] == row["team_points_seen"]  # the same view, seeded
    assert bare["team_points_fused"] > 0 and bare["team_cells_mapped"] > 0
