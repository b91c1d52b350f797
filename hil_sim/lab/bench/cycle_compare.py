"""``safer-hil bench cycle --baseline REV --results``: the same bench of another commit, run back to
back in a child process, and the before/after table in docs/results/cycle.md.

The baseline's code (``fsw``, ``hil_sim``, ``config``) is exported from git into a temporary
directory and its own ``safer-hil bench cycle`` runs there (``--mission-steps 0``: the cycle
only), one grid and one repeat per child, interleaved with this commit's repeats, so a change
of the machine's load hits both alike; its stage table is read from its output (the line
format every version prints: ``  <stage> <min> (<median>) ms``). Both scale to the reference
machine by the same yardstick, timed between the runs of each grid.
"""

from __future__ import annotations

import argparse
import io
import os
import re
import shlex
import subprocess
import sys
import tarfile
import tempfile
from dataclasses import dataclass
from pathlib import Path

from hil_sim.lab.cycle_budget import CYCLE_GOALS_S, CYCLE_STAGES, BudgetConfig
from hil_sim.lab.results import REPO, markdown_table, write_results

Stages = dict[int, dict[str, float | None]]  # grid -> stage -> min CPU s here (None: not run)
_GRID = re.compile(r"map (\d+)x(\d+) cells")
_STAGE = re.compile(r"^\s+(" + "|".join(CYCLE_STAGES) + r")\s+(n/a|\d+(?:\.\d+)?)\b")
_CHILD = "import sys; from hil_sim.cli import main; sys.exit(main(sys.argv[1:]))"


class BaselineError(Exception):
    """The baseline commit could not be exported or its bench failed (one line)."""


@dataclass(frozen=True)
class Baseline:
    """The baseline commit's stage figures (min over its repeats), measured interleaved with this
    commit's on the same grids, so both share each grid's yardstick."""

    commit: str
    stages: Stages


def parse_stages(text: str) -> Stages:
    """The stage table of a ``bench cycle`` output, per grid size."""
    out: Stages = {}
    grid: int | None = None
    for line in text.splitlines():
        m = _GRID.search(line)
        if m:
            grid = int(m.group(1))
            out[grid] = {}
            continue
        m = _STAGE.match(line)
        if m and grid is not None:
            out[grid][m.group(1)] = None if m.group(2) == "n/a" else float(m.group(2)) / 1e3
    return out


def _git(*argv: str) -> bytes:
    try:
        return subprocess.run(["git", *argv], cwd=REPO, capture_output=True, check=True, timeout=120).stdout
    except (OSError, subprocess.SubprocessError) as err:
        detail = getattr(err, "stderr", None) or str(err)
        text = detail.decode(errors="replace") if isinstance(detail, bytes) else str(detail)
        raise BaselineError(f"git {argv[0]} failed: {text.strip().splitlines()[-1] if text.strip() else err}") from err


class BaselineRunner:
    """Another commit's ``bench cycle``, exported from git once (``with`` block: its temporary
    directory) and run one grid and one repeat at a time in a child process, so its runs
    interleave with this commit's (the same load for both)."""

    def __init__(self, rev: str, args: argparse.Namespace) -> None:
        try:
            sha = _git("rev-parse", "--verify", "--quiet", f"{rev}^{{commit}}").decode().strip()
        except BaselineError:
            sha = ""
        if not sha:
            raise BaselineError(f"--baseline {rev}: not a commit of this checkout")
        self.commit = sha[:12]
        self._tar = _git("archive", "--format=tar", sha, "fsw", "hil_sim", "config")
        self._args = args
        self._tmp: tempfile.TemporaryDirectory[str] | None = None

    def __enter__(self) -> BaselineRunner:
        self._tmp = tempfile.TemporaryDirectory(prefix="bench-cycle-baseline-")
        with tarfile.open(fileobj=io.BytesIO(self._tar)) as tf:
            tf.extractall(self._tmp.name, filter="data")
        return self

    def __exit__(self, *exc: object) -> None:
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def stages(self, grid: int) -> dict[str, float | None]:
        """One repeat of the baseline's cycle on one grid: CPU s per stage."""
        if self._tmp is None:
            raise BaselineError("the baseline runner is used outside its with block")
        a = self._args
        cmd = [sys.executable, "-c", _CHILD, "bench", "cycle", "--grids", str(grid), "--repeats", "1",
               "--mission-steps", "0", "--scenario", a.scenario, "--seed", str(a.seed)]
        if a.config is not None:
            cmd += ["--config", str(Path(a.config).resolve())]
        env = {**os.environ, "PYTHONPATH": self._tmp.name}
        try:
            done = subprocess.run(cmd, cwd=self._tmp.name, env=env, capture_output=True, text=True, check=False)
        except OSError as err:
            raise BaselineError(f"the baseline's bench could not start: {err}") from err
        if done.returncode != 0:
            tail = (done.stderr.strip().splitlines() or ["no output"])[-1]
            raise BaselineError(f"the baseline's bench cycle exited {done.returncode}: {tail}")
        st = parse_stages(done.stdout).get(grid)
        if st is None or set(st) != set(CYCLE_STAGES):
            raise BaselineError(f"the baseline's bench cycle printed no stage table for {grid}x{grid}")
        return st


def min_stages(runs: list[dict[str, float | None]]) -> dict[str, float | None]:
    """Per stage, the least of the runs (None where a stage did not run)."""
    return {s: (None if any(r[s] is None for r in runs) else min(float(r[s] or 0.0) for r in runs))
            for s in CYCLE_STAGES}


def _ms(v: float | None) -> float | None:
    return None if v is None else 1e3 * v


def _ratio(a: float | None, b: float | None) -> str | None:
    return None if a is None or b is None or a <= 0 else f"{b / a:.2f}x"


def cycle_tables(budget: BudgetConfig, after: Stages, yard_s: dict[int, float], before: Baseline | None) -> str:
    """The results file's tables: every stage and the cycle on the reference machine (ms), the
    growth per stage between grid sizes, the issue's cycle goals. ``yard_s``: the yardstick
    here per grid (timed between that grid's runs)."""
    yards = ", ".join(f"{1e3 * yard_s[n]:.1f} ms ({n}x{n})" for n in sorted(after))
    lines = [f"Yardstick (hil_sim/lab/bench/yardstick.py) here: {yards}, timed between each grid's runs; "
             f"{1e3 * budget.yardstick_ref_s:.1f} ms on the reference machine (config/budget.toml). "
             "`ref` figures are CPU ms here x the reference's yardstick / this grid's, min of the repeats."]
    if before is not None:
        lines.append(f"Before: commit `{before.commit}`, its own bench run in a child process, one repeat "
                     "at a time, interleaved with this commit's repeats (the same load and yardstick).")
    rows = []
    for n in sorted(after):
        scale = b_scale = budget.yardstick_ref_s / yard_s[n]
        stages = [*CYCLE_STAGES, "cycle"]
        for stage in stages:
            a: float | None
            b: float | None
            if stage == "cycle":
                a = sum(v for v in after[n].values() if v is not None)
                b = None if before is None else sum(v for v in before.stages.get(n, {}).values() if v is not None)
            else:
                a = after[n].get(stage)
                b = None if before is None else before.stages.get(n, {}).get(stage)
            row: dict[str, object] = {"grid": f"{n}x{n}", "stage": stage}
            if before is not None:
                row["before ref ms"] = _ms(None if b is None else b * b_scale)
            row["after ref ms"] = _ms(None if a is None else a * scale)
            row["after here ms"] = _ms(a)
            if before is not None:
                row["after / before"] = _ratio(None if b is None else b * b_scale, None if a is None else a * scale)
            rows.append(row)
    out = "\n\n".join([" ".join(lines), "## Stages\n\n" + markdown_table(rows)])
    grids = sorted(after)
    growth = []
    for n1, n2 in zip(grids, grids[1:], strict=False):
        bound = budget.stage_growth_max * (n2 / n1) ** 2
        for stage in CYCLE_STAGES:
            row = {"grids": f"{n1} -> {n2}", "stage": stage, "bound": f"{bound:.1f}x"}
            if before is not None:
                row["before"] = _ratio(before.stages.get(n1, {}).get(stage), before.stages.get(n2, {}).get(stage))
            a1, a2 = after[n1].get(stage), after[n2].get(stage)
            row["after"] = _ratio(a1, a2)
            row["after within"] = None if a1 is None or a2 is None or a1 <= 0 else ("yes" if a2 / a1 <= bound else "no")
            growth.append(row)
    if growth:
        out += "\n\n## Growth per stage\n\n" + markdown_table(growth)
    goals = []
    for n in grids:
        if n not in CYCLE_GOALS_S:
            continue
        scale = b_scale = budget.yardstick_ref_s / yard_s[n]
        a = sum(v for v in after[n].values() if v is not None) * scale
        row = {"grid": f"{n}x{n}", "goal ref s": CYCLE_GOALS_S[n]}
        if before is not None:
            row["before ref s"] = sum(v for v in before.stages.get(n, {}).values() if v is not None) * b_scale
        row |= {"after ref s": a, "after met": "yes" if a <= CYCLE_GOALS_S[n] else "no"}
        goals.append(row)
    if goals:
        out += "\n\n## Sensing cycle against the goals (issue 30)\n\n" + markdown_table(goals)
    return out


def bench_command(args: argparse.Namespace) -> str:
    """The command line that reproduces this run (every option that changes a figure)."""
    argv = ["safer-hil", "bench", "cycle", "--grids", *map(str, args.grids), "--repeats", str(args.repeats),
            "--mission-steps", str(args.mission_steps), "--scenario", args.scenario, "--seed", str(args.seed)]
    for opt, value in (("--config", args.config), ("--budget", args.budget), ("--cpu-factor", args.cpu_factor),
                       ("--baseline", args.baseline)):
        if value is not None:
            argv += [opt, str(value)]
    return shlex.join([*argv, "--results"])


def write_cycle_results(args: argparse.Namespace, budget: BudgetConfig, after: Stages, yard_s: dict[int, float],
                        before: Baseline | None) -> Path | None:
    """docs/results/cycle.md: the command line and :func:`cycle_tables`."""
    return write_results("cycle", bench_command(args), cycle_tables(budget, after, yard_s, before), kind="bench")
