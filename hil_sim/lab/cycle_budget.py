"""The target budget of ``safer-hil bench cycle`` (config/budget.toml; docs/architecture.md).

Measured times here are first scaled to the reference machine by the yardstick measured in the
same run (``hil_sim.lab.bench.yardstick``: ``ref_s = here_s * yardstick_ref_s / yardstick_here_s``),
then projected to the flight computer by one factor, ``target_s = ref_s * cpu_factor`` (one core
of the reference machine against the SRR's 266 MHz PC-104 CPU), and compared with the table:
each sensing-cycle stage, the foreground per frame and the peak RSS.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from fsw.framework.params import load, param

DEFAULT_BUDGET = Path(__file__).resolve().parents[2] / "config" / "budget.toml"
CYCLE_STAGES = ("rectify", "stereo", "register", "merge", "edge", "next_view")
CYCLE_GOALS_S = {256: 0.5, 512: 1.5}  # the sensing cycle's goals (issue 30), s on the reference machine per grid


@dataclass(frozen=True)
class CycleBudget:
    """Seconds on the target for each stage of one sensing cycle, and the whole cycle."""

    rectify_s: float = param(1.0, lo=0.0, hi=1e6, units="s", doc="rectify the pair")
    stereo_s: float = param(3.0, lo=0.0, hi=1e6, units="s", doc="stereo to 3-D points")
    register_s: float = param(1.0, lo=0.0, hi=1e6, units="s", doc="registration of the view against the map")
    merge_s: float = param(2.0, lo=0.0, hi=1e6, units="s", doc="P_V, the points' world covariance, the merge")
    edge_s: float = param(1.5, lo=0.0, hi=1e6, units="s", doc="edge cells and polygon fit")
    next_view_s: float = param(6.5, lo=0.0, hi=1e6, units="s", doc="the next-view search")
    total_s: float = param(15.0, lo=0.0, hi=1e6, units="s", doc="the whole cycle")


@dataclass(frozen=True)
class BudgetConfig:
    """config/budget.toml."""

    cpu_factor: float = param(30.0, lo=1.0, hi=1000.0, doc="target time / time on one core of the reference machine")
    yardstick_ref_s: float = param(0.030, lo=1e-4, hi=100.0, units="s",
                                   doc="the bench's yardstick workload on one core of the reference machine")
    stage_growth_max: float = param(1.1, lo=1.0, hi=100.0,
                                    doc="a stage's time may grow this many times its map cells' growth")
    frame_period_s: float = param(0.1, lo=0.001, hi=10.0, units="s", doc="minor frame")
    foreground_ms_per_frame: float = param(15.0, lo=0.0, hi=1e6, units="ms",
                                           doc="all foreground tasks, target ms per frame")
    peak_rss_mb: float = param(200.0, lo=1.0, hi=1e6, units="MB", doc="flight peak RSS")
    slack_slice_ms: float = param(20.0, lo=0.1, hi=1e6, units="ms",
                                  doc="longest slack-job slice, here (not scaled): the executive's slice bound")
    cycle: CycleBudget = field(default_factory=CycleBudget)


def load_budget(path: str | Path = DEFAULT_BUDGET) -> BudgetConfig:
    """Read and validate the budget table (``ConfigError`` on a bad file)."""
    return load(BudgetConfig, path)


def verdict(target: float, budget: float) -> str:
    """``ok`` within the budget, else how far over it."""
    return "ok" if target <= budget else f"OVER x{target / budget:.1f}" if budget > 0 else "OVER"
