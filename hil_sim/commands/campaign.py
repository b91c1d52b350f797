"""``safer-hil campaign``: a Monte-Carlo HIL campaign from a spec (docs/experiments.md)."""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

HELP = "run a campaign of missions (scenario families x seeds x methods x faults), locally or on Dask"
DESCRIPTION = (
    "Expand SPEC.toml (scenario families with parameter grids or seeded random samples, seeds, "
    "methods, fault sets at given bench times) into independent lockstep missions and run them on "
    "a local pool (--jobs) or a Dask cluster (--scheduler tcp://HOST:PORT). Each mission is "
    "deterministic from its seed and stored in DIR/missions/ when it ends; a rerun skips stored "
    "missions (resume). A mission that raises, hangs past timeout_s or dies is recorded as "
    "error/killed and the campaign goes on. Writes DIR/results.parquet and results.csv (a row a "
    "mission) and DIR/report.md with plots. Exit 0 when every mission ran (whatever its outcome), "
    "1 when some raised or were killed, 2 on a bad spec or arguments."
)
SCHEDULER = re.compile(r"^(tcp|tls|inproc|ucx)://[^\s/]+$")


def add_arguments(p: argparse.ArgumentParser) -> None:
    from fsw.settings import DEFAULT_CONFIG

    p.add_argument("spec", nargs="?", type=Path, default=DEFAULT_CONFIG.parent / "campaigns" / "default.toml",
                   help="campaign spec (TOML); config/campaigns/smoke.toml is a 4-mission smoke test")
    p.add_argument("--out", type=Path, default=None,
                   help="output directory (%(default)s: out/campaign/<name> of the spec)")
    p.add_argument("--jobs", type=int, default=2, help="missions in parallel on this machine")
    p.add_argument("--scheduler", default=None,
                   help="Dask scheduler address tcp://HOST:PORT (%(default)s: the local pool, --jobs)")
    p.add_argument("--retry-failed", action="store_true", help="rerun stored missions that raised or were killed")
    p.add_argument("--dry-run", action="store_true", help="list the missions and exit")
    p.add_argument("--report-only", action="store_true",
                   help="run nothing: table and report from the missions stored so far (a partial campaign)")


def run(args: argparse.Namespace) -> int:
    from fsw.framework.params import ConfigError
    from hil_sim.lab.campaign.spec import expand, load_spec

    if args.jobs < 1:
        print("safer-hil campaign: --jobs must be >= 1", file=sys.stderr)
        return 2
    if args.scheduler is not None and not SCHEDULER.match(args.scheduler):
        print(f"safer-hil campaign: --scheduler {args.scheduler!r} is not an address like tcp://127.0.0.1:8786",
              file=sys.stderr)
        return 2
    try:
        spec = load_spec(args.spec)
    except ConfigError as err:
        print(f"safer-hil campaign: {err}", file=sys.stderr)
        return 2
    missions = expand(spec)
    out = args.out or Path("out/campaign") / spec.campaign.name
    if args.dry_run:
        for m in missions:
            print(f"{m.id}\t{m.scenario}\tmethod {m.method}\tseed {m.seed}\tfaults {m.fault_set}")
        print(f"{len(missions)} missions")
        return 0
    return run_campaign(spec.campaign.name, missions, out, args.jobs, args.scheduler, args.retry_failed,
                        args.report_only)


def with_fault_timing(rows: list[dict], missions: list) -> list[dict]:  # type: ignore[type-arg]
    """Each row with ``fault_start_s`` (the earliest start of its faults, None when clean) and
    ``fault_in_mission`` (that start came before the mission ended: a fault window drawn after
    the end never happened, and the row must not count as a faulted mission that coped)."""
    starts = {m.id: min((f["start_s"] for f in m.faults), default=None) for m in missions}
    out = []
    for r in rows:
        t = starts.get(r["id"])
        hit = None if t is None or r.get("sim_s") is None else bool(t < r["sim_s"])
        out.append({**r, "fault_start_s": t, "fault_in_mission": hit})
    return out


def run_campaign(name: str, missions: list, out: Path, jobs: int, scheduler: str | None,  # type: ignore[type-arg]
                 retry_failed: bool = False, report_only: bool = False) -> int:
    import time

    from hil_sim.lab.campaign.execute import FAILED, execute
    from hil_sim.lab.campaign.report import write_report
    from hil_sim.lab.campaign.table import write_table

    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(f"safer-hil campaign: cannot create {out}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    try:
        rows, reused = execute(missions, out, jobs, scheduler, retry_failed, report_only=report_only)
    except OSError as exc:  # e.g. the scheduler cannot be reached
        print(f"safer-hil campaign: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    wall = time.perf_counter() - t0
    if not rows:
        print(f"safer-hil campaign: no mission stored in {out / 'missions'} yet", file=sys.stderr)
        return 1
    rows = with_fault_timing(rows, missions)
    write_table(out, rows)
    where = f"Dask scheduler {scheduler}" if scheduler else f"local pool, {jobs} jobs"
    extra = (f"Run on {where}: {len(rows) - reused} missions in {wall:.0f} s wall clock "
             f"({reused} reused from an earlier run).\n")
    if report_only:
        state = "every mission" if len(rows) == len(missions) else "a partial campaign"
        mission_s = sum(r["wall_s"] or 0.0 for r in rows)
        extra = (f"Report rebuilt from the stored rows ({state}: {len(rows)} of {len(missions)} missions; "
                 f"their own wall time summed {mission_s:.0f} s).\n")
    h = write_report(out, rows, name, extra)
    bad = sum(r["outcome"] in FAILED for r in rows)
    print(f"{len(rows)} missions ({reused} reused) in {wall:.0f} s; outcomes: "
          + ", ".join(f"{k} {v}" for k, v in h["outcomes"].items() if v))
    print(f"report: {out / 'report.md'}; table: {out / 'results.parquet'} and results.csv")
    return 1 if bad else 0
