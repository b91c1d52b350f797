"""``safer-hil bench cycle`` and its budget table (issue 15 item 5)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from fsw.framework.params import ConfigError
from hil_sim.cli import main
from hil_sim.lab.bench.cycle_compare import Baseline, cycle_tables, parse_stages
from hil_sim.lab.bench.yardstick import yardstick_s
from hil_sim.lab.cycle_budget import CYCLE_STAGES, DEFAULT_BUDGET, load_budget, verdict
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
    assert main(["bench", "cycle", "--baseline", "no-such-commit", "--grids", "16"]) == 2
    assert "not a commit" in capsys.readouterr().err


def test_budget_table_defaults_and_rejects_bad_values(tmp_path: Path) -> None:
    b = load_budget()
    assert b.cpu_factor == 30.0
    stages = (b.cycle.rectify_s, b.cycle.stereo_s, b.cycle.register_s, b.cycle.merge_s, b.cycle.edge_s,
              b.cycle.next_view_s)
    assert sum(stages) <= b.cycle.total_s + 1e-9  # the stage budgets fit the cycle's
    assert b.slack_slice_ms == 20.0  # the slice bound, here
    assert b.yardstick_ref_s > 0 and b.stage_growth_max == 1.1  # 4.4x for 4x the cells
    bad = tmp_path / "b.toml"
    bad.write_text("cpu_factor = 30.0\n[cycle]\nstereo_s = -1.0\n")
    with pytest.raises(ConfigError):
        load_budget(bad)
    bad.write_text("cpu_factor = 30.0\nunknown_key = 1\n")
    with pytest.raises(ConfigError):
        load_budget(bad)
    assert verdict(1.0, 2.0) == "ok" and verdict(4.0, 2.0) == "OVER x2.0"


def test_task_ms_per_frame_sums_foreground_tasks_only() -> None:
    """Per task: summed execution time on the host timer over the frames run; rate-group and
    executive components (not activated as tasks) are left out; ``total`` is the sum."""
    a = SimpleNamespace(name="devices", host=SimpleNamespace(total_s=0.010))
    b = SimpleNamespace(name="motion", host=SimpleNamespace(total_s=0.030))
    exe = SimpleNamespace(frame=20, groups=[SimpleNamespace(members=[a]),
                                            SimpleNamespace(members=[b])],
                          tasks={"rg_fast": None})
    out = task_ms_per_frame(exe)
    assert out == {"devices": 0.5, "motion": 1.5, "total": 2.0}
    assert "task_ms_per_frame" in WALL_CLOCK_FIELDS  # not compared between seeded runs


@pytest.fixture(scope="module")
def small_run() -> str:
    """One small ``bench cycle`` run (a 16 x 16 map, one timed run per stage, then the short
    lockstep mission) whose output both tests below read."""
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(["bench", "cycle", "--grids", "16", "--repeats", "1", "--mission-steps", "1"]) == 0
    return buf.getvalue()


@pytest.mark.slow
def test_bench_cycle_prints_breakdown(small_run: str) -> None:
    """A small run: every stage, the projection and the verdicts are printed."""
    out = small_run
    for word in ("capture", "rectify", "stereo", "register", "merge", "edge", "next_view", "cycle",
                 "peak RSS", "target", "the flown pipeline", "yardstick"):
        assert word in out
    stages = parse_stages(out)  # what a later --baseline run reads back from this version
    assert list(stages) == [16] and set(stages[16]) == set(CYCLE_STAGES)
    assert all(v is None or v > 0 for v in stages[16].values())


@pytest.mark.slow
def test_bench_cycle_prints_the_longest_slice(small_run: str) -> None:
    """Issue 15: the short lockstep mission reports the foreground per task and the longest
    slack-job slice per submitting task against the 20 ms bound."""
    out = small_run
    line = next(ln for ln in out.splitlines() if "longest slack-job slice" in ln)
    assert "perception" in line and "bound 20 ms here" in line
    assert "motion" in out and "total" in out


_OLD_OUTPUT = """
sensing cycle (the flown pipeline), lab after the start panorama, map 256x256 cells of 3.00 cm; the view registered:
  stage         here min (median)    target   budget
  capture        580.1 (  580.1) ms   (bench renderer, not flight work: not in the total)
  rectify          2.4 (    2.4) ms     0.07s     1.0s ok
  stereo         136.9 (  136.9) ms     4.11s     3.0s OVER x1.4
  register        34.8 (   34.8) ms     1.04s     1.0s OVER x1.0
  merge           74.7 (   74.7) ms     2.24s     2.0s OVER x1.1
  edge            17.4 (   17.4) ms     0.52s     1.5s ok
  next_view      305.0 (  305.0) ms     9.15s     6.5s OVER x1.4
  cycle          571.1 (sum of min) ms    17.13s    15.0s OVER x1.1

sensing cycle (the flown pipeline), lab after the start panorama, map 512x512 cells of 1.50 cm; the view registered:
  stage         here min (median)    target   budget
  rectify     n/a (no calibration)                 1.0s
  stereo         134.5 (  134.5) ms     4.04s     3.0s OVER x1.3
  register        32.9 (   32.9) ms     0.99s     1.0s ok
  merge          243.1 (  243.1) ms     7.29s     2.0s OVER x3.6
  edge            71.9 (   71.9) ms     2.16s     1.5s OVER x1.4
  next_view     1471.8 ( 1471.8) ms    44.15s     6.5s OVER x6.8
"""


def test_baseline_table_is_read_from_an_older_bench_output() -> None:
    """The stage table of a bench cycle printed before the yardstick existed (the baseline of a
    before/after run) is read per grid, ms to s, n/a as None; capture and cycle are not stages."""
    st = parse_stages(_OLD_OUTPUT)
    assert list(st) == [256, 512]
    assert st[256] == {"rectify": 0.0024, "stereo": 0.1369, "register": 0.0348, "merge": 0.0747,
                       "edge": 0.0174, "next_view": 0.305}
    assert st[512]["rectify"] is None and st[512]["next_view"] == 1.4718


def test_cycle_tables_scale_by_the_yardstick_and_check_growth() -> None:
    """Figures scale by the reference's yardstick over the run's; a stage growing more than
    stage_growth_max x the cells' growth is flagged; the cycle is held against the goals."""
    budget = load_budget()
    after = {256: dict.fromkeys(CYCLE_STAGES, 0.01), 512: dict.fromkeys(CYCLE_STAGES, 0.04)}
    after[512]["edge"] = 0.05  # 5x for 4x the cells
    before = Baseline("abc", parse_stages(_OLD_OUTPUT))
    half = budget.yardstick_ref_s / 2.0  # this run's machine: 2x faster
    md = cycle_tables(budget, after, {256: half, 512: half}, before)
    rows = {tuple(c.strip() for c in ln.strip("|").split("|")[:2]): ln for ln in md.splitlines() if ln.startswith("|")}
    assert "| 20 |" in rows[("256x256", "merge")] and "| 10 |" in rows[("256x256", "merge")]  # ref ms, here ms
    assert rows[("256 -> 512", "edge")].rstrip().endswith("| no |")
    assert rows[("256 -> 512", "merge")].rstrip().endswith("| yes |")
    assert "| 3.25x |" in rows[("256 -> 512", "merge")]  # the baseline's 74.7 -> 243.1 ms
    goal = next(ln for ln in md.splitlines() if ln.startswith("| 256x256 | 0.5 |"))
    assert goal.rstrip().endswith("| yes |")


def test_yardstick_is_a_positive_cpu_time() -> None:
    assert 0.0 < yardstick_s(1) < 5.0
