"""``safer-hil experiment team --rows``: the table of the scenes a run finished, without running any."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hil_sim.cli import main

ROW = {"seed": 4, "slope_deg": 70.0, "drop_m": 3.0, "targets": 3, "reachable_truth": 2, "reachable_full": 2,
       "reachable_reduced": 1, "verdicts_differ": 1, "path_ratio_max": 1.25, "hazard_cells_lost": 7,
       "map_bytes": 4000, "truth_reasons": "-; -; slack", "reached": 1, "missed": 1,
       "missed_why": "the lengths hold it elsewhere", "off_the_way": 4, "fix_requests": 3, "unconfirmed": 1,
       "state": "DONE", "tether_violations": 0, "hazard_cells_entered": 0, "unknown_cells_entered": 0, "fixes": 2,
       "fix_bytes_down": 244, "fix_bytes_up": 24, "path_m": 5.0, "sim_s": 60.0, "safe_reason": "",
       "_fixes": [[3.5, 1.0, 0.2, 3.0], [4.5, 2.0, 0.4, 20.0]]}


def test_rows_report_the_finished_scenes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("SAFER_RESULTS_DIR", str(tmp_path / "results"))
    rows = tmp_path / "team_rows.jsonl"
    rows.write_text(json.dumps(ROW) + "\n" + json.dumps({**ROW, "seed": 2, "path_ratio_max": 1.05}) + "\n")
    assert main(["experiment", "team", "--rows", str(rows), "--out", str(tmp_path / "out")]) == 0
    page = (tmp_path / "results" / "team.md").read_text()
    assert "| scenes (seeds) / targets | 2 (2, 4) / 6 |" in page
    assert "| path length reduced / full | 1.150 / 1.250 |" in page
    assert "| scenes with a path over 10 % longer on the reduced map | 1 |" in page
    assert "| why the truth-reachable targets were missed (mission's reason: count) | " \
           "the lengths hold it elsewhere: 2 |" in page
    assert "| fixes answered / fix requests (total) | 4 / 6 |" in page
    assert "| 3-4 | 2 | 1.00 / 1.00 | 0.20 / 0.20 | 100 % |" in page and "| 4-5 | 2 | 2.00 / 2.00 |" in page
    assert "| 4-5 | 2 | 2.00 / 2.00 | 0.40 / 0.40 | 0 % |" in page  # NEES 20 > 12.59
    capsys.readouterr()


@pytest.mark.parametrize("text", ["", "not json\n", "[1, 2]\n"])
def test_bad_rows_exit_2(tmp_path: Path, text: str, capsys: pytest.CaptureFixture[str]) -> None:
    rows = tmp_path / "rows.jsonl"
    rows.write_text(text)
    assert main(["experiment", "team", "--rows", str(rows), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "--rows" in err and "Traceback" not in err
