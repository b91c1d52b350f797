"""``safer-hil experiment coverage``: the paper's Figures 7 and 8 (docs/algorithm.md §7).

Runs the five mapping methods and the oracle over several seeds as full lockstep missions
(``hil_sim.mission.mission_run``), then writes ``coverage.csv`` (one row per run and step),
``coverage.md`` (mapped cells at the last step per method: mean, spread, ratio to Method 1
and to the oracle), ``fig7_coverage.png`` (mapped cells against imaging steps, mean and
min-max band over seeds) and ``fig8_expected_vs_obtained.png`` (expected against obtained
new cells of every view the planner rated, Methods 3-5: the view's own new cells, not a look's
before it in the step). Each run's own summary lands in
``DIR/runs/<method>_seed<k>/``.

``--scenario lab,terrain`` runs several scenarios (a generated family takes each seed as a new
terrain): each gets its own report in ``DIR/<scenario>/`` as above, and ``DIR/coverage.md`` joins
them with the information model's prediction pooled over every scenario (per method: the median
and 10th-90th percentile of obtained over expected new cells of every rated view) and Figure 8
over all of them (``fig8_expected_vs_obtained.png``, one colour per scenario).

``coverage.md`` and ``coverage.json`` end with the paper's claims (issue 5, "Done when")
checked against these runs: each claim whose methods were run, its measured value, its
target and whether it is met (:func:`claims`).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from hil_sim.lab.results import command_line, write_results
from hil_sim.mission.mission_report import UNRATED_VIEWS, prediction_ratios

HELP = "mapped cells vs imaging steps for methods 1-5 and the oracle (paper Figures 7 and 8)"
METHODS = ("1", "2", "3", "4", "5", "oracle")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default="lab",
                   help="lab, cliff, mars, terrain or file:PATH; several separated by commas (lab,terrain)")
    p.add_argument("--steps", type=int, default=20, help="imaging steps after the panorama")
    p.add_argument("--seeds", type=int, default=3, help="seeds 0..N-1 per method")
    p.add_argument("--methods", default=",".join(METHODS), help="comma-separated subset")
    p.add_argument("--what-if", action="append", default=[], metavar="KEY=VALUE",
                   help="also rate the rated views again with this [nbv.visibility] value (repeatable), "
                        "e.g. prior_corr_len_m=2")
    p.add_argument("--jobs", type=int, default=2, help="missions run in parallel (processes)")
    p.add_argument("--out", type=Path, default=Path("out/coverage"), help="output directory")


def _one(scenario: str, method: str, steps: int, seed: int, out: str) -> dict[str, Any]:
    from hil_sim.mission.mission_run import RunSpec, run_mission

    return run_mission(RunSpec(scenario, method, steps, seed, transmit=False, out=Path(out)), mode="fresh")


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    scenarios = [s.strip() for s in args.scenario.split(",") if s.strip()]
    bad = [m for m in methods if m not in METHODS]
    if bad or not scenarios or args.seeds < 1 or args.steps < 1 or args.jobs < 1:
        why = bad or ("no scenario" if not scenarios else "seeds/steps/jobs must be >= 1")
        print(f"safer-hil experiment coverage: bad arguments ({why})", file=sys.stderr)
        return 2
    try:
        from hil_sim.lab.prediction_check import what_if_values

        what_if = what_if_values(args.what_if)
    except ValueError as err:
        print(f"safer-hil experiment coverage: --what-if: {err}", file=sys.stderr)
        return 2
    many = len(scenarios) > 1
    outs = {sc: args.out / _slug(sc) if many else args.out for sc in scenarios}
    for o in outs.values():
        o.mkdir(parents=True, exist_ok=True)
    runs = [(sc, m, s) for sc in scenarios for s in range(args.seeds) for m in methods]
    results: dict[str, dict[tuple[str, int], dict[str, Any]]] = {sc: {} for sc in scenarios}
    failed: list[str] = []
    with (
        ProcessPoolExecutor(max_workers=args.jobs) as pool,
        tqdm(total=len(runs), desc=f"coverage {args.scenario}", unit="mission") as bar,
    ):
        futs = {
            pool.submit(_one, sc, m, args.steps, s, str(outs[sc] / "runs" / f"{m}_seed{s}")): (sc, m, s)
            for sc, m, s in runs
        }
        for fut in as_completed(futs):
            sc, m, s = futs[fut]
            try:
                results[sc][(m, s)] = fut.result()
            except Exception as exc:  # noqa: BLE001 - one failed mission is reported, the rest go on
                failed.append(f"{sc} method {m} seed {s}: {type(exc).__name__}: {exc}")
                bar.set_postfix_str(f"{sc} method {m} seed {s}: FAILED")
            else:
                bar.set_postfix_str(f"{sc} method {m} seed {s}: {results[sc][(m, s)]['mapped_cells']} cells")
            bar.update()
    if failed:
        print("safer-hil experiment coverage: missions failed, no report written:\n  " + "\n  ".join(failed),
              file=sys.stderr)
        return 1
    for sc in scenarios:
        write_report(outs[sc], sc, args.steps, methods, args.seeds, results[sc])
    if not many:
        md = (args.out / "coverage.md").read_text()
        figures = [args.out / "fig7_coverage.png", args.out / "fig8_expected_vs_obtained.png"]
    else:
        md = pooled_report(args.out, scenarios, methods, args.seeds, results)
        md += "".join("\n" + (outs[sc] / "coverage.md").read_text() for sc in scenarios)
        (args.out / "coverage.md").write_text(md)
        figures = [args.out / "fig8_expected_vs_obtained.png"]
        for sc in scenarios:  # each scenario's Figure 7 under its own name
            fig7 = args.out / f"fig7_coverage_{_slug(sc)}.png"
            fig7.write_bytes((outs[sc] / "fig7_coverage.png").read_bytes())
            figures.append(fig7)
    split = prediction_split(outs, scenarios, methods, args.seeds, what_if)
    (args.out / "coverage.md").write_text(md + split)
    print(md + split)
    write_results("coverage", command_line("coverage"), md + split, figures)
    return 0


def prediction_split(outs: dict[str, Path], scenarios: list[str], methods: list[str], seeds: int,
                     what_if: dict[str, dict[str, float]]) -> str:
    """Per information method, its rated views' expected and obtained new cells split into the
    model's parts against the truth (``hil_sim.lab.prediction_check``), over every scenario and seed."""
    from fsw.settings import DEFAULT_CONFIG, load_settings
    from hil_sim.lab.prediction_check import decompose_run, split_table

    rho = load_settings(str(DEFAULT_CONFIG)).nbv.visibility.stereo_return
    lines = ["", "## Where the expected new cells part from the obtained (hil_sim.lab.prediction_check)", ""]
    for m in (m for m in ("3", "4", "5") if m in methods):
        views = [v for sc in scenarios for s in range(seeds)
                 for v in decompose_run(outs[sc] / "runs" / f"{m}_seed{s}", sc, s, what_if=what_if)]
        lines += [f"Method {m}, {', '.join(scenarios)}: " + split_table(views, rho)]
    return "\n".join(lines) + "\n"


def _slug(spec: str) -> str:
    """A file name for a scenario spec."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in spec)[:60]


def pooled_report(out: Path, scenarios: list[str], methods: list[str], seeds: int,
                  results: dict[str, dict[tuple[str, int], dict[str, Any]]]) -> str:
    """The information model's prediction over every scenario (per method and per scenario: rated
    views, median and 10th-90th percentile of obtained / expected new cells; the pooled median
    judged against 0.8-1.25) and Figure 8 over all scenarios, written to ``out``; the markdown."""
    lines = [f"# The information model's prediction over {', '.join(scenarios)} ({seeds} seeds each)", "",
             "| method | scenario | rated views | obtained / expected: median | 10th percentile | 90th percentile | "
             "target (median) |", "|---|---|---|---|---|---|---|"]
    shown: list[str] = [m for m in ("3", "4", "5") if m in methods]
    for m in shown:
        for sc in [*scenarios, "all"]:
            pick = scenarios if sc == "all" else [sc]
            pr = prediction_ratios([st for c in pick for s in range(seeds) for st in results[c][(m, s)]["steps"]])
            if "median_ratio" not in pr:
                lines.append(f"| {m} | {sc} | 0 | - | - | - | |")
                continue
            ok = 0.8 <= pr["median_ratio"] <= 1.25
            judged = ("met" if ok else "NOT MET") if sc == "all" else ""
            lines.append(f"| {m} | {'**all**' if sc == 'all' else sc} | {pr['rated_steps']} | "
                         f"{pr['median_ratio']:.2f} | {pr['p10_ratio']:.2f} | {pr['p90_ratio']:.2f} | "
                         f"{'0.8-1.25 ' + judged if judged else ''} |")
    figure8(out, shown or ["5"],
            lambda m: [(f"{sc} ({{n}} views)", _rated_pairs(results[sc], m, seeds) if m in methods else None)
                       for sc in scenarios],
            "Figure 8: expected vs obtained new cells per rated view, every scenario and seed")
    return "\n".join(lines) + "\n"


def figure8(out: Path, shown: Sequence[str], series: Any, title: str) -> None:
    """``fig8_expected_vs_obtained.png`` in ``out``: one panel per method of ``shown``, each
    series of ``series(method)`` (``(label, pairs)``: ``{n}`` in the label is its number of
    rated views; ``pairs`` the ``(..., 2)`` expected and obtained new cells, None: none)
    scattered against the line obtained = expected and the 0.8-1.25 band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, axes = plt.subplots(1, len(shown), figsize=(5.2 * len(shown), 4.6), constrained_layout=True, squeeze=False)
    for ax, m in zip(axes[0], shown, strict=True):
        top = 1.0
        for label, pairs in series(m):
            pairs = np.zeros((0, 0, 2)) if pairs is None else pairs
            e, o = pairs[..., 0].ravel(), pairs[..., 1].ravel()
            ok = np.isfinite(e)
            top = max(top, float(np.nanmax(pairs)) if ok.any() else 1.0)
            ax.scatter(e[ok], o[ok], s=14, label=label.format(n=int(ok.sum())))
        top *= 1.05
        ax.plot([0, top], [0, top], "k-", lw=1, label="obtained = expected")
        ax.fill_between([0, top], [0, 0.8 * top], [0, 1.25 * top], color="0.5", alpha=0.15, label="0.8-1.25")
        ax.set_xlim(0, top)
        ax.set_ylim(0, top)
        ax.set_title(f"Method {m}")
        ax.set_xlabel("expected new cells (model)")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left")
    axes[0][0].set_ylabel("obtained new cells (the view's own)")
    fig.suptitle(title)
    fig.savefig(out / "fig8_expected_vs_obtained.png", dpi=100)
    plt.close(fig)


@dataclass(frozen=True)
class Claim:
    """One of the paper's claims (issue 5) checked against the runs."""

    text: str
    value: float
    target: str
    met: bool
    detail: str


def claims(results: dict[tuple[str, int], dict[str, Any]], methods: list[str], seeds: int,
           steps: int) -> list[Claim]:
    """The issue-5 claims that the methods run allow checking, with the measured values.

    Mapped cells are means over seeds at the last step. "Expected matches obtained" is the
    median over every view the planner rated (``mission_report.prediction_ratios``: the view's own
    new cells over its expected; looks and refused moves have no prediction); "falls toward zero"
    compares Method 3's mean obtained and expected new cells of its rated views over its last
    five steps."""
    final = {m: float(curves(results, m, seeds, steps)[:, -1].mean()) for m in methods}
    out: list[Claim] = []

    def ratio(a: str, b: str, target: float, text: str) -> None:
        if a in final and b in final and final[b] > 0:
            r = final[a] / final[b]
            out.append(Claim(text, r, f">= {target:g}", r >= target, f"{final[a]:.0f} / {final[b]:.0f}"))

    ratio("5", "1", 10.0, "Method 5 maps >= 10x the cells of Method 1")
    ratio("5", "oracle", 0.9, "Method 5 reaches >= 0.9 x the oracle")
    ratio("5", "3", 1.3, "Method 5 maps >= 30 % more than Method 3")
    if "4" in final and "5" in final:
        r = final["5"] / final["4"] if final["4"] > 0 else float("inf")
        out.append(Claim("Method 5 maps more than Method 4", r, "> 1", r > 1.0,
                         f"{final['5']:.0f} / {final['4']:.0f}"))
    if "5" in methods:
        pr = prediction_ratios([st for s in range(seeds) for st in results[("5", s)]["steps"]])
        r = float(pr.get("median_ratio", float("nan")))
        out.append(Claim("Method 5's new cells per view match its expected within 25 % (median over rated views)",
                         r, "0.8 .. 1.25", 0.8 <= r <= 1.25,
                         f"obtained / expected, {pr['rated_steps']} views, 10th-90th percentile "
                         f"{pr.get('p10_ratio', float('nan')):.2f}-{pr.get('p90_ratio', float('nan')):.2f}"))
    if "3" in methods:
        exp_m, obt_m = _expected_obtained(results, "3", seeds)
        late = [(float(e), float(o)) for e, o in zip(exp_m[-5:], obt_m[-5:], strict=True) if e == e]
        e5 = sum(e for e, _ in late) / len(late) if late else 0.0
        if len(exp_m) >= 5 and e5 > 0:
            o5 = sum(o for _, o in late) / len(late)
            out.append(Claim("Method 3's obtained new cells fall toward zero while its expected stay high",
                             o5 / e5, "<= 0.1 (last 5 steps)", o5 / e5 <= 0.1,
                             f"last 5 steps: expected {e5:.0f}, obtained {o5:.0f} per step"))
    runs = list(results.values())
    viol = sum(int(r["edge_violations"]) for r in runs)
    out.append(Claim("No edge violation in any run", viol, "0", viol == 0, f"{len(runs)} missions"))
    slips = sum(int(r["slips"]) for r in runs)
    out.append(Claim("Zero slips at 10 Hz", slips, "0", slips == 0, f"{len(runs)} missions"))
    return out


def _ratio(a: float, b: float, unit: str = "") -> str:
    """``a / b`` for the table, or "-" when the reference method was not run."""
    return f"{a / b:.2f}{unit}" if b == b and b > 0 else "-"


def curves(results: dict[tuple[str, int], dict[str, Any]], method: str, seeds: int, steps: int) -> Any:
    """(seeds, steps+1) mapped cells per step; a run that ended early keeps its last value."""
    import numpy as np

    out = np.zeros((seeds, steps + 1))
    for s in range(seeds):
        recs = {r["step"]: r["mapped_cells"] for r in results[(method, s)]["steps"]}
        last = 0
        for k in range(steps + 1):
            last = recs.get(k, last)
            out[s, k] = last
    return out


def write_report(
    out: Path, scenario: str, steps: int, methods: list[str], seeds: int, results: dict[tuple[str, int], dict[str, Any]]
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    with (out / "coverage.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(
            [
                "scenario",
                "method",
                "seed",
                "step",
                "mapped_cells",
                "expected_new_cells",
                "obtained_new_cells",
                "view",
                "view_new_cells",
                "x",
                "y",
                "yaw",
                "pan",
                "tilt",
                "lift",
            ]
        )
        for (m, s), r in sorted(results.items()):
            for st in r["steps"]:
                p = st["pose"]
                w.writerow(
                    [
                        scenario,
                        m,
                        s,
                        st["step"],
                        st["mapped_cells"],
                        round(st["expected_new_cells"], 1),
                        st["obtained_new_cells"],
                        st.get("view", ""),
                        st.get("view_new_cells", -1),
                        *(round(p[k], 4) for k in ("x", "y", "yaw", "pan", "tilt", "lift")),
                    ]
                )
    curve = {m: curves(results, m, seeds, steps) for m in methods}
    final = {m: c[:, -1] for m, c in curve.items()}
    added = {m: c[:, -1] - c[:, 0] for m, c in curve.items()}  # by the imaging steps (panorama excluded)
    ref1 = final["1"].mean() if "1" in final else float("nan")
    add1 = added["1"].mean() if "1" in added else float("nan")
    refo = final["oracle"].mean() if "oracle" in final else float("nan")
    lines = [
        f"# Coverage, {scenario} scenario, {steps} steps, {seeds} seeds",
        "",
        "| method | mapped cells at last step (mean) | min | max | vs Method 1 | vs oracle | "
        "added by steps 1.. (mean) | added vs Method 1 | steps taken (mean) | edge violations | slips | "
        "map RMSE (cm) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for m in methods:
        f = final[m]
        runs = [results[(m, s)] for s in range(seeds)]
        rmse = [r["map_rmse_m"] for r in runs if r["map_rmse_m"] is not None]
        taken = np.mean([max(st["step"] for st in r["steps"]) for r in runs])
        lines.append(
            f"| {m} | {f.mean():.0f} | {f.min():.0f} | {f.max():.0f} | {_ratio(f.mean(), ref1, 'x')} | "
            f"{_ratio(f.mean(), refo)} | {added[m].mean():.0f} | {_ratio(added[m].mean(), add1, 'x')} | {taken:.1f} | "
            f"{sum(r['edge_violations'] for r in runs)} | {sum(r['slips'] for r in runs)} | {100 * np.mean(rmse):.2f} |"
        )
    for m in ("3", "4", "5"):
        if m in methods:
            exp, obt = _expected_obtained(results, m, seeds)
            pr = prediction_ratios([st for s in range(seeds) for st in results[(m, s)]["steps"]])
            lines.append("")
            lines.append(
                f"Method {m}: expected / obtained new cells of the rated views per step (mean over seeds, "
                "steps 1..; - no rated view): "
                + ", ".join("-" if e != e else f"{e:.0f}/{o:.0f}" for e, o in zip(exp, obt, strict=True))
            )
            if "median_ratio" in pr:
                lines.append(
                    f"Method {m}: obtained / expected per rated view: median {pr['median_ratio']:.2f}, "
                    f"10th-90th percentile {pr['p10_ratio']:.2f}-{pr['p90_ratio']:.2f} over {pr['rated_steps']} "
                    f"views; {pr['unrated_steps']} unrated views (looks, refused moves) added "
                    f"{pr['unrated_new_cells']} cells"
                )
    checked = claims(results, methods, seeds, steps)
    lines += ["", "## The paper's claims (issue 5)", "", "| claim | measured | target | |", "|---|---|---|---|"]
    for c in checked:
        lines.append(f"| {c.text} | {c.value:.3g} ({c.detail}) | {c.target} | {'met' if c.met else 'NOT MET'} |")
    (out / "coverage.md").write_text("\n".join(lines) + "\n")
    (out / "coverage.json").write_text(
        json.dumps(
            {
                "scenario": scenario,
                "steps": steps,
                "seeds": seeds,
                "methods": {m: {"final_mean": float(final[m].mean()), "final": final[m].tolist()} for m in methods},
                "claims": [asdict(c) for c in checked],
            },
            indent=2,
        )
    )

    fig, ax = plt.subplots(figsize=(7, 4.5), constrained_layout=True)
    for m in methods:
        c = curves(results, m, seeds, steps)
        k = np.arange(steps + 1)
        ax.plot(k, c.mean(0), "o-", ms=3, label=f"method {m}" if m != "oracle" else "oracle")
        ax.fill_between(k, c.min(0), c.max(0), alpha=0.15)
    ax.set_xlabel("stereo imaging step")
    ax.set_ylabel("mapped grid cells")
    ax.set_title(f"Figure 7: mapped cells vs steps ({scenario}, {seeds} seeds, band = min-max)")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.savefig(out / "fig7_coverage.png", dpi=100)
    plt.close(fig)

    shown = [m for m in ("3", "4", "5") if m in methods] or ["5"]
    figure8(out, shown, lambda m: [("rated views ({n})", _rated_pairs(results, m, seeds) if m in methods else None)],
            "Figure 8: expected vs obtained new cells per step (every rated view of every seed)")


def _rated_pairs(results: dict[tuple[str, int], dict[str, Any]], method: str, seeds: int) -> Any:
    """(seeds, steps, 2) expected and obtained new cells of each step's view (steps 1..), the
    view's own cells (a look before it in the step is not its yield); NaN where the view was not
    one the planner rated (a look, a refused move: no prediction, ``mission_report.UNRATED_VIEWS``)."""
    import numpy as np

    rows = []
    for s in range(seeds):
        row = []
        for r in results[(method, s)]["steps"]:
            if r["step"] < 1:
                continue
            own = int(r.get("view_new_cells", -1))
            rated = r.get("view", "") not in UNRATED_VIEWS and own >= 0
            row.append((float(r["expected_new_cells"]), float(own)) if rated else (np.nan, np.nan))
        rows.append(row)
    n = max((len(r) for r in rows), default=0)
    arr = np.full((len(rows), n, 2), np.nan)
    for k, row in enumerate(rows):
        if row:
            arr[k, : len(row)] = row
    return arr


def _expected_obtained(results: dict[tuple[str, int], dict[str, Any]], method: str, seeds: int) -> tuple[Any, Any]:
    """Per step (1..), the mean over seeds of the rated views' expected and obtained new cells
    (:func:`_rated_pairs`; NaN at a step no seed rated)."""
    import warnings

    import numpy as np

    arr = _rated_pairs(results, method, seeds)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a step with no rated view: NaN
        return np.nanmean(arr[..., 0], axis=0), np.nanmean(arr[..., 1], axis=0)
