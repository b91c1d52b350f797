"""``safer-hil bench nbv`` as a command: help, bad input, and one small run that prints figures."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fsw.settings import DEFAULT_CONFIG
from hil_sim.cli import main


def test_bench_nbv_help(capsys: pytest.CaptureFixture[str]) -> None:
    """BRIEF: a CLI has a --help that explains."""
    with pytest.raises(SystemExit) as exc:
        main(["bench", "nbv", "--help"])
    assert exc.value.code == 0
    assert "brute" in capsys.readouterr().out


def test_bench_nbv_bad_input_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """BRIEF: a bad config file or argument gives a one-line error and exit code 2."""
    bad = tmp_path / "fsw.toml"
    text = DEFAULT_CONFIG.read_text()
    assert "\nw_motion = 5.0" in text
    bad.write_text(text.replace("\nw_motion = 5.0", "\nw_motion = -3.0"))
    assert main(["bench", "nbv", "--config", str(bad)]) == 2
    assert "w_motion" in capsys.readouterr().err
    assert main(["bench", "nbv", "--rays", "10"]) == 2
    assert main(["bench", "nbv", "--seed", "-1"]) == 2
    with pytest.raises(SystemExit) as exc:
        main(["bench", "nbv", "--scenario", "moon"])
    assert exc.value.code == 2


@pytest.mark.slow
def test_bench_nbv_prints_rate_and_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                         ) -> None:
    """Issue 5 done-when: the bench prints poses rated per second and the P_V error against
    the reference (computed, not canned: the JSON figures match the run)."""
    out, cfg = tmp_path / "fig.json", tmp_path / "fsw.toml"
    text = DEFAULT_CONFIG.read_text()
    assert "\nmax_travel_m = 2.5" in text
    cfg.write_text(text.replace("\nmax_travel_m = 2.5", "\nmax_travel_m = 0.5"))
    assert main(["bench", "nbv", "--scenario", "synthetic", "--warmup-views", "0", "--config",
                 str(cfg), "--ref-poses", "2", "--repeat", "1", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    fig = json.loads(out.read_text())
    assert "poses/s" in text and "mean abs error" in text
    assert fig["poses"] > 100 and fig["poses_per_s"] > 0
    assert fig["ref_cells"] > 1000 and 0.0 <= fig["pv_mae"] <= 0.05
