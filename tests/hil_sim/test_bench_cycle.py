"""``safer-hil bench cycle`` and its budget table (issue 15 item 5)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from fsw.framework.params import ConfigError
from hil_sim.cli import main
from hil_sim.lab.cycle_budget import DEFAULT_BUDGET, load_budget, verdict
from hil_sim.mission.mission_report import WALL_CLOCK_FIELDS, task_ms_per_frame


def test_bench_cycle_help(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["bench", "cycle", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "cpu_factor" in out and "budget" in out and "CAVEAT" in out


def test_bench_cycle_bad_input_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "cycle", "--repeats", "0"]) == 2
    assert main(["bench", "cycle", "--grids", "8"]) == 2
    assert main(["bench", "cycle", "--cpu-factor", "0.5"]) == 2
    bad = tmp_path / "budget.toml"
    bad.write_text(DEFAULT_BUDGET.read_text().replace("cpu_factor = 30.0", "cpu_factor = nan"))
    assert main(["bench", "cycle", "--budget", str(bad)]) == 2
    assert "cpu_factor" in capsys.readouterr().err
    assert main(["bench", "cycle", "--budget", str(tmp_path / "missing.toml")]) == 2


def test_budget_table_defaults_and_rejects_bad_values(tmp_path: Path) -> None:
    b = load_budget()
    assert b.cpu_factor == 30.0
    stages = (b.cycle.rectify_s, b.cycle.stereo_s, b.cycle.register_s, b.cycle.merge_s, b.cycle.edge_s,
              b.cycle.next_view_s)
    assert sum(stages) <= b.cycle.total_s + 1e-9  # the stage budgets fit the cycle's
    assert b.slack_slice_ms == 20.0  # the slice bound, here
    bad = tmp_path / "b.toml"
    bad.write_text("cpu_factor = 30.0\n[cycle]\nstereo_s = -1.0\n")
    with pytest.raises(ConfigError):
        load_budget(bad)
    bad.write_text("cpu_factor = 30.0\nunknown_key = 1\n")
    with pytest.raises(ConfigError):
        load_budget(bad)
    assert verdict(1.0, 2.0) == "ok" and verdict(4.0, 2.0) == "OVER x2.0"


def test_task_ms_per_frame_sums_foreground_tasks_only() -> None:
    """Per task: summed execution time over the frames run; rate-group and executive
    components (not activated as tasks) are left out; ``total`` is the sum."""
    a = SimpleNamespace(name="devices", total_s=0.010)
    b = SimpleNamespace(name="motion", total_s=0.030)
    exe = SimpleNamespace(frame=20, groups=[SimpleNamespace(members=[a]),
                                            SimpleNamespace(members=[b])],
                          tasks={"rg_fast": None})
    out = task_ms_per_frame(exe)
    assert out == {"devices": 0.5, "motion": 1.5, "total": 2.0}
    assert "task_ms_per_frame" in WALL_CLOCK_FIELDS  # not compared between seeded runs


@pytest.mark.slow
def test_bench_cycle_prints_breakdown(capsys: pytest.CaptureFixture[str]) -> None:
    """A small run: every stage, the projection and the verdicts are printed."""
    assert main(["bench", "cycle", "--grids", "64", "--repeats", "1",
                 "--mission-steps", "0"]) == 0
    out = capsys.readouterr().out
    for word in ("capture", "rectify", "stereo", "register", "merge", "edge", "next_view", "cycle",
                 "peak RSS", "target", "the flown pipeline"):
        assert word in out


@pytest.mark.slow
def test_bench_cycle_prints_the_longest_slice(capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 15: the short lockstep mission reports the foreground per task and the longest
    slack-job slice per submitting task against the 20 ms bound."""
    assert main(["bench", "cycle", "--grids", "16", "--repeats", "1", "--mission-steps", "1"]) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if "longest slack-job slice" in ln)
    assert "perception" in line and "bound 20 ms here" in line
    assert "motion" in out and "total" in out
