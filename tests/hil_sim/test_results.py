"""``hil_sim.lab.results``: the result file an experiment command writes (docs/results/<experiment>.md)."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import pytest

from hil_sim.lab import results


def test_result_file_has_date_commit_command_table_and_figures(tmp_path: Path) -> None:
    fig = tmp_path / "fig7.png"
    fig.write_bytes(b"\x89PNG fake")
    when = dt.datetime(2030, 1, 2, 3, 4, tzinfo=dt.UTC)
    table = "# Coverage\n\n" + results.markdown_table([{"method": "5", "cells": 3012.0, "note": None}])
    path = results.write_results("coverage", "safer-hil experiment coverage --seeds 3", table, [fig],
                                 now=when, directory=tmp_path / "res")
    assert path == tmp_path / "res" / "coverage.md"
    text = path.read_text()
    assert text.startswith("# Results: `safer-hil experiment coverage`\n")
    assert "- date: 2030-01-02 03:04 UTC" in text
    assert "- command: `safer-hil experiment coverage --seeds 3`" in text
    commit = text.split("- commit: `", 1)[1].split("`", 1)[0]
    assert commit == results.commit() and commit
    assert "\n## Coverage\n" in text  # the command's heading sits under the file's title
    assert "| 5 | 3012 | - |" in text
    assert "![fig7](img/coverage_fig7.png)" in text
    assert (tmp_path / "res" / "img" / "coverage_fig7.png").read_bytes() == b"\x89PNG fake"
    assert not list((tmp_path / "res").glob("*.tmp"))


def test_rerun_replaces_the_file(tmp_path: Path) -> None:
    results.write_results("link", "a", "| x |\n|---|\n| 1 |", directory=tmp_path)
    results.write_results("link", "b", "| x |\n|---|\n| 2 |", directory=tmp_path)
    text = (tmp_path / "link.md").read_text()
    assert "`b`" in text and "| 2 |" in text and "| 1 |" not in text


def test_a_file_named_apart_from_its_experiment_names_both(tmp_path: Path) -> None:
    path = results.write_results("face-map-heldout", "safer-hil experiment face-map --seed 30", "| x |\n|---|",
                                 directory=tmp_path)
    assert path is not None
    assert path.read_text().startswith("# Results: `safer-hil experiment face-map` (face-map-heldout)\n")


def test_bad_name_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="experiment name"):
        results.write_results("../escape", "c", "t", directory=tmp_path)


def test_environment_chooses_the_directory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(results.ENV, str(tmp_path / "elsewhere"))
    assert results.results_dir() == tmp_path / "elsewhere"
    monkeypatch.delenv(results.ENV)
    assert results.results_dir() == results.REPO / "docs" / "results"


def test_command_line_is_what_the_user_typed() -> None:
    assert results.command_line("link", ["experiment", "link", "--transport", "udp", "--out", "a b"]) == \
        "safer-hil experiment link --transport udp --out 'a b'"


def test_markdown_table_formats_cells() -> None:
    t = results.markdown_table([{"a": 0.123456, "b": "x|y"}, {"a": None}], ["a", "b"])
    assert t.splitlines() == ["| a | b |", "|---|---|", "| 0.1235 | x\\|y |", "| - | - |"]
