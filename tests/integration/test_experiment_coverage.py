"""Issue 5 item 7: ``safer-hil experiment coverage`` report: the table, the figures and the
paper's claims computed from the runs (synthetic summaries here; real missions in
test_mission_run.py and docs/experiments.md)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from hil_sim.cli import main as hil_main
from hil_sim.lab.experiments.experiment_coverage import claims, write_report

POSE = {"x": 0.0, "y": 0.0, "yaw": 0.0, "pan": 0.0, "tilt": 0.0, "lift": 0.5}


def _run(gains: list[tuple[float, int]], violations: int = 0, slips: int = 0, view: str = "5") -> dict[str, Any]:
    """A summary whose step k (k >= 1) expected ``gains[k-1][0]`` and obtained ``gains[k-1][1]``
    with a view the planner rated (``view``)."""
    mapped, steps = 1000, [{"step": 0, "mapped_cells": 1000, "expected_new_cells": 0.0,
                             "obtained_new_cells": 1000, "pose": POSE, "view": "panorama", "view_new_cells": 100}]
    for k, (exp, obt) in enumerate(gains, start=1):
        mapped += obt
        steps.append({"step": k, "mapped_cells": mapped, "expected_new_cells": exp,
                      "obtained_new_cells": obt, "pose": POSE, "view": view, "view_new_cells": obt})
    return {"steps": steps, "edge_violations": violations, "slips": slips, "map_rmse_m": 0.04,
            "mapped_cells": mapped}


def _results(m3_late: int) -> dict[tuple[str, int], dict[str, Any]]:
    steps = 6
    res = {}
    for s in range(2):
        res[("1", s)] = _run([(0.0, 100)] * 3)  # ended early: keeps its last value
        res[("3", s)] = _run([(3000.0, 3000)] + [(2000.0, m3_late)] * (steps - 1))
        res[("5", s)] = _run([(3000.0, 3000)] + [(1500.0, 1800)] * (steps - 1))
        res[("oracle", s)] = _run([(3000.0, 3000)] + [(1800.0, 1900)] * (steps - 1))
    return res


def test_claims_are_computed_from_the_runs() -> None:
    methods = ["1", "3", "5", "oracle"]
    c = {x.text: x for x in claims(_results(m3_late=5), methods, seeds=2, steps=6)}
    m1 = c["Method 5 maps >= 10x the cells of Method 1"]
    assert m1.value == pytest.approx((1000 + 3000 + 5 * 1800) / 1300) and m1.met
    assert c["Method 5 reaches >= 0.9 x the oracle"].value == pytest.approx(13000 / 13500)
    assert c["Method 5 maps >= 30 % more than Method 3"].met
    track = c["Method 5's new cells per view match its expected within 25 % (median over rated views)"]
    assert track.value == pytest.approx(1800 / 1500) and track.met  # 2 views at 1.0, 10 at 1.2
    chase = c["Method 3's obtained new cells fall toward zero while its expected stay high"]
    assert chase.value == pytest.approx(5 / 2000) and chase.met
    assert c["No edge violation in any run"].met and c["Zero slips at 10 Hz"].met
    assert "Method 5 maps more than Method 4" not in c  # Method 4 was not run

    # The same claims fail when the runs say otherwise.
    bad = _results(m3_late=1500)
    bad[("5", 1)] = _run([(3000.0, 3000)] + [(1500.0, 1800)] * 5, violations=1, slips=2)
    bad[("5", 0)] = _run([(1000.0, 3000)] + [(600.0, 1800)] * 5)  # obtained 3x the expected on every view
    c = {x.text: x for x in claims(bad, methods, seeds=2, steps=6)}
    assert not c["Method 5's new cells per view match its expected within 25 % (median over rated views)"].met
    assert not c["Method 3's obtained new cells fall toward zero while its expected stay high"].met
    assert not c["Method 5 maps >= 30 % more than Method 3"].met
    assert not c["No edge violation in any run"].met and not c["Zero slips at 10 Hz"].met


def test_report_files(tmp_path: Path) -> None:
    write_report(tmp_path, "lab", 6, ["1", "3", "5", "oracle"], 2, _results(m3_late=5))
    md = (tmp_path / "coverage.md").read_text()
    data = json.loads((tmp_path / "coverage.json").read_text())
    # mean, min, max, vs Method 1, vs oracle, added after the panorama, added vs Method 1, steps
    assert "| 5 | 13000 | 13000 | 13000 | 10.00x | 0.96 | 12000 | 40.00x | 6.0 |" in md
    assert "| 1 | 1300 | 1300 | 1300 | 1.00x | 0.10 | 300 | 1.00x | 3.0 |" in md
    assert "## The paper's claims (issue 5)" in md
    assert "Method 5: obtained / expected per rated view: median 1.20, 10th-90th percentile" in md
    # looks and refused moves carry no prediction: left out of the per-step means and of Figure 8
    looked = _results(m3_late=5)
    looked[("5", 0)]["steps"][2]["view"] = "look"
    write_report(tmp_path, "lab", 6, ["1", "3", "5", "oracle"], 2, looked)
    assert "over 11 views; 1 unrated views" in (tmp_path / "coverage.md").read_text()
    assert md.count("| met |") + md.count("| NOT MET |") == 7
    assert data["methods"]["1"]["final"] == [1300.0, 1300.0]
    assert len(data["claims"]) == 7
    rows = (tmp_path / "coverage.csv").read_text().splitlines()
    assert len(rows) == 1 + 2 * (4 + 7 + 7 + 7)
    for png in ("fig7_coverage.png", "fig8_expected_vs_obtained.png"):
        assert (tmp_path / png).stat().st_size > 10_000


@pytest.mark.parametrize("argv", [["--methods", "1,7"], ["--seeds", "0"], ["--steps", "x"]])
def test_bad_arguments_exit_2(argv: list[str], tmp_path: Path) -> None:
    with pytest.raises(SystemExit) as e:
        rc = hil_main(["experiment", "coverage", "--out", str(tmp_path), *argv])
        raise SystemExit(rc)
    assert e.value.code == 2


def test_table_without_the_reference_methods(tmp_path: Path) -> None:
    """Run without Method 1 and the oracle (the cliff's 4-vs-5 run): their ratios read "-"."""
    write_report(tmp_path, "cliff", 6, ["3", "5"], 2, _results(m3_late=5))
    md = (tmp_path / "coverage.md").read_text()
    assert "| 5 | 13000 | 13000 | 13000 | - | - | 12000 | - | 6.0 |" in md
    assert "nan" not in md


def test_prediction_pooled_over_scenarios(tmp_path: Path) -> None:
    """Several scenarios (--scenario lab,terrain): each scenario's views and all of them pooled,
    per method, with the pooled median judged; Figure 8 over every scenario."""
    from hil_sim.lab.experiments.experiment_coverage import pooled_report

    lab = _results(m3_late=5)  # Method 5: 2 views at 1.0, 10 at 1.2
    far = {k: _run([(1000.0, 2000)] * 6) for k in lab}  # every view obtains 2x its expected
    md = pooled_report(tmp_path, ["lab", "terrain"], ["3", "5"], 2, {"lab": lab, "terrain": far})
    assert "| 5 | lab | 12 | 1.20 |" in md and "| 5 | terrain | 12 | 2.00 |" in md
    assert "| 5 | **all** | 24 | 1.60 |" in md and "0.8-1.25 NOT MET" in md
    assert (tmp_path / "fig8_expected_vs_obtained.png").stat().st_size > 10_000
