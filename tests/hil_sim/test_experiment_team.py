"""``safer-hil experiment team``: its input checks and where its report goes (the scenes
themselves are the experiment's run; docs/team.md, "Running a team mission")."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hil_sim.cli import main


@pytest.mark.parametrize("argv", [
    ["experiment", "team", "--scenes", "0"],
    ["experiment", "team", "--jobs", "0"],
    ["experiment", "team", "--max-s", "nan"],
    ["experiment", "team", "--results-name", "../elsewhere"],
    ["experiment", "team", "--results-name", "Team"],
    ["experiment", "team", "--cliffbot-config", "/nonexistent/cliffbot.toml"],
])
def test_bad_input_exits_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(argv) == 2
    assert "Traceback" not in capsys.readouterr().err


def _row(seed: int) -> dict[str, object]:
    """A scene's row as :func:`hil_sim.lab.experiments.experiment_team.scene` writes it, without
    a mission (the report's map and truth figures only)."""
    return {"seed": seed, "slope_deg": 70.0, "drop_m": 5.0, "targets": 3, "reachable_truth": 2,
            "reachable_full": 2, "reachable_reduced": 1, "verdicts_differ": 1, "path_ratio_max": 1.02,
            "hazard_cells_lost": 0, "map_bytes": 9000, "truth_reasons": "-; slack; -", "_fixes": []}


def test_a_held_out_run_writes_its_own_results_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``--results-name`` writes ``NAME.md`` beside the others and leaves ``team.md`` alone."""
    results = tmp_path / "results"
    results.mkdir()
    monkeypatch.setenv("SAFER_RESULTS_DIR", str(results))
    rows = tmp_path / "team_rows.jsonl"
    rows.write_text("".join(json.dumps(_row(s)) + "\n" for s in (31, 30)))
    argv = ["experiment", "team", "--rows", str(rows), "--out", str(tmp_path / "out"),
            "--results-name", "team-heldout"]
    assert main(argv) == 0
    assert not (results / "team.md").exists()
    text = (results / "team-heldout.md").read_text()
    assert "(team-heldout)" in text  # the title names the file, the command its experiment
    assert "| scenes (seeds) / targets | 2 (30-31) / 6 |" in text


def test_the_scenes_fly_the_cliffbots_flight_file(tmp_path: Path) -> None:
    """The bench missions take the Cliff-bot's tether, ground, navigation and mission sections from
    its flight file (``--cliffbot-config``, default ``config/cliffbot.toml``), not the defaults."""
    from fsw.settings import DEFAULT_CONFIG, load_settings
    from hil_sim.team.team_run import TeamSetup

    text = (DEFAULT_CONFIG.parent / "cliffbot.toml").read_text()
    assert "tension_guard_n = 2.0" in text
    changed = tmp_path / "cliffbot.toml"
    changed.write_text(text.replace("tension_guard_n = 2.0", "tension_guard_n = 2.5"))
    setup = TeamSetup.from_settings(load_settings(changed), max_s=60.0)
    assert setup.mission.tension_guard_n == 2.5 and setup.max_s == 60.0
    assert setup.tether == load_settings(changed).tether and setup.nav == load_settings(changed).cliffbot_nav


def _scene_or_refused(spec: str, seed: int, *args: object) -> dict[str, object]:
    """The experiment's ``scene`` for the test below: seed 39 is refused as the scenario refuses it."""
    from hil_sim.world import ScenarioError

    if seed == 39:
        raise ScenarioError("cliff-team: the Cliff-bot's start y = -0.5 m is not on the plateau")
    return _row(seed)


def _broken_scene(spec: str, seed: int, *args: object) -> dict[str, object]:
    raise RuntimeError("a bug")


def test_seeds_the_scenario_refuses_are_named_and_the_rest_reported(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """A seed whose scene the scenario refuses to build is no failed scene: the report is written
    for the others and names the refused seed with why; a scene that fails still writes none."""
    from hil_sim.lab.experiments import experiment_team

    monkeypatch.setenv("SAFER_RESULTS_DIR", str(tmp_path / "results"))
    monkeypatch.setattr(experiment_team, "scene", _scene_or_refused)
    argv = ["experiment", "team", "--scenes", "3", "--seed", "38", "--out", str(tmp_path / "out"),
            "--results-name", "team-heldout"]
    assert main(argv) == 0
    text = (tmp_path / "results" / "team-heldout.md").read_text()
    assert "| scenes (seeds) / targets | 2 (38, 40) / 6 |" in text
    assert "- 39: cliff-team: the Cliff-bot's start y = -0.5 m is not on the plateau" in text
    assert "seed 39 not run, the scenario refuses it" in capsys.readouterr().err
    monkeypatch.setattr(experiment_team, "scene", _broken_scene)
    (tmp_path / "results" / "team-heldout.md").unlink()
    assert main(argv) == 1
    assert not (tmp_path / "results" / "team-heldout.md").exists()
    assert "seed 38: RuntimeError: a bug" in capsys.readouterr().err
