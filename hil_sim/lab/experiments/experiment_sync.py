"""``safer-hil experiment sync``: the two-way map sync through the hostile relay, with restarts (docs/sync.md).

For each seed, a seeded scene (``hil_sim.team.team_sync.make_scene``: terrain, each agent's
views, a few ground changes) is synced between the RECON-bot and the Cliff-bot over the
bench's radio channel model with ``--loss``, ``--ber``, ``--duplicate``, ``--reorder`` and an
outage of ``--outage-s`` from ``--outage-at-s``, in four cases: ``outage`` (the channel alone),
``kill-recon`` (the RECON-bot killed in the middle of the outage and restarted from its
checkpoint), ``kill-cliff`` (the Cliff-bot killed after the outage, restarted from its
checkpoint) and ``replica-lost`` (the Cliff-bot restarted with nothing: the one case where a
full resend is expected). Per run: the replicas' hashes equal at the end, sync rounds from the
link's return (or the restart, whichever is later) to equal hashes, sync bytes over the bytes
of the minimal deltas, the DIGEST and HOLDINGS bytes of those over them, air bytes over them,
full resends. Runs go in ``--jobs`` processes;
the table goes to ``--out``/sync.md and docs/results/sync.md.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

from hil_sim.lab.results import command_line, markdown_table, write_results

HELP = "two-way map sync through loss, bit errors, duplication, reordering, an outage and restarts"
CASES = ("outage", "kill-recon", "kill-cliff", "replica-lost")
Row = dict[str, float | int | str | bool | None]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seeds", type=int, default=30, help="scenes (seeds 0..N-1)")
    p.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, of {', '.join(CASES)}")
    p.add_argument("--size", type=int, default=128, help="map side in cells (16-cell tiles)")
    p.add_argument("--rounds", type=int, default=24, help="sync rounds with new views")
    p.add_argument("--round-s", type=float, default=10.0, help="seconds between sync rounds")
    p.add_argument("--loss", type=float, default=0.3, help="packet loss, each direction")
    p.add_argument("--ber", type=float, default=3e-5, help="bit error rate")
    p.add_argument("--duplicate", type=float, default=0.1, help="duplication probability")
    p.add_argument("--reorder", type=float, default=0.1, help="reordering probability")
    p.add_argument("--outage-at-s", type=float, default=60.0, help="outage start")
    p.add_argument("--outage-s", type=float, default=60.0, help="outage duration (0: none)")
    p.add_argument("--rate-bps", type=float, default=9600.0, help="radio bit rate")
    p.add_argument("--jobs", type=int, default=2, help="runs at the same time")
    p.add_argument("--out", type=Path, default=Path("out/experiments/sync"), help="output dir")


def one(case: str, seed: int, args: dict[str, float]) -> Row:
    """One run (a process of its own under ``--jobs``)."""
    from dataclasses import replace

    from fsw.comm.team.sync_config import SyncConfig
    from hil_sim.link.radio_channel import RadioChannelConfig
    from hil_sim.team.team_sync import Kill, make_scene, run_sync

    o_at, o_len = args["outage_at_s"], args["outage_s"]
    ch = RadioChannelConfig(rate_bps=args["rate_bps"], loss=args["loss"], ber=args["ber"],
                            duplicate=args["duplicate"], reorder=args["reorder"],
                            outages=((o_at, o_len),) if o_len > 0 else ())
    scene = make_scene(seed, n=int(args["size"]), rounds=int(args["rounds"]))
    back = o_at + o_len
    kills: tuple[Kill, ...] = ()
    if case == "kill-recon":
        kills = (Kill(0, o_at + 0.4 * o_len, 10.0),)
    elif case == "kill-cliff":
        kills = (Kill(1, back + 3.5 * args["round_s"], 5.0),)
    elif case == "replica-lost":
        kills = (Kill(1, back + 3.5 * args["round_s"], 5.0, from_checkpoint=False),)
    since = max([back if o_len > 0 else 0.0, *(k.at_s + k.down_s for k in kills)])
    res = run_sync(scene, ch, seed, cfg=replace(SyncConfig(), rate_bps=args["rate_bps"]),
                   round_s=args["round_s"], kills=kills)
    minimal = max(1, res.minimal_bytes)
    control = sum(s.digest_bytes_in + s.holdings_bytes_in for s in res.stats.values())
    return {"case": case, "seed": seed, "hash_equal": res.hash_equal, "extra_rounds": res.extra_rounds,
            "rounds_to_equal": res.rounds_to_equal_after(since), "bytes_ratio": round(res.sync_bytes / minimal, 4),
            "control_ratio": round(control / minimal, 4),
            "air_ratio": round(res.air_bytes / minimal, 4), "sync_bytes": res.sync_bytes,
            "minimal_bytes": res.minimal_bytes, "full_resends": res.full_resends,
            "resent_tiles": sum(s.resent_tiles for s in res.stats.values()),
            "adopted": sum(s.adopted for s in res.stats.values()),
            "bad_packets": sum(s.bad_packets for s in res.stats.values())}


def summarise(rows: list[Row], cases: list[str]) -> list[Row]:
    import numpy as np

    out: list[Row] = []
    for c in cases:
        rs = [r for r in rows if r["case"] == c]
        if not rs:
            continue
        rte = [r["rounds_to_equal"] for r in rs]
        conv = [float(x) for x in rte if isinstance(x, int)]
        ratio = np.array([float(r["bytes_ratio"] or 0) for r in rs])
        control = np.array([float(r["control_ratio"] or 0) for r in rs])
        air = np.array([float(r["air_ratio"] or 0) for r in rs])
        within = sum(1 for x in rte if isinstance(x, int) and x <= 3)
        out.append({
            "case": c, "runs": len(rs), "hash equal at end": sum(bool(r["hash_equal"]) for r in rs),
            "equal within 3 rounds": within, "rounds median": float(np.median(conv)) if conv else None,
            "rounds worst": max(conv) if len(conv) == len(rs) else None,
            "bytes / minimal median": float(np.median(ratio)), "bytes / minimal worst": float(ratio.max()),
            "control / minimal median": float(np.median(control)), "control / minimal worst": float(control.max()),
            "air / minimal median": float(np.median(air)),
            "full resends": sum(int(r["full_resends"] or 0) for r in rs),
            "bad packets dropped": sum(int(r["bad_packets"] or 0) for r in rs)})
    return out


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    if any(c not in CASES for c in cases) or args.seeds < 1 or args.jobs < 1 or args.size < 16 or args.rounds < 1:
        print(f"safer-hil experiment sync: bad arguments (cases of {', '.join(CASES)}; seeds, jobs, rounds >= 1; "
              "size >= 16)", file=sys.stderr)
        return 2
    params = {k: float(getattr(args, k)) for k in ("size", "rounds", "round_s", "loss", "ber", "duplicate", "reorder",
                                                   "outage_at_s", "outage_s", "rate_bps")}
    runs = [(c, s) for s in range(args.seeds) for c in cases]
    rows: list[Row] = []
    with ProcessPoolExecutor(max_workers=args.jobs) as pool, tqdm(total=len(runs), desc="sync", unit="run") as bar:
        futs = {pool.submit(one, c, s, params): (c, s) for c, s in runs}
        for fut in as_completed(futs):
            r = fut.result()
            rows.append(r)
            bar.set_postfix_str(f"{r['case']} seed {r['seed']}: {r['rounds_to_equal']} rounds, x{r['bytes_ratio']}")
            bar.update()
    rows.sort(key=lambda r: (cases.index(str(r["case"])), int(r["seed"] or 0)))
    summary = summarise(rows, cases)
    md = "\n".join([
        "# Two-way map sync through the hostile relay",
        "",
        f"{args.seeds} seeded scenes of {args.size} x {args.size} cells (16-cell tiles), {args.rounds} rounds "
        f"of new views every {args.round_s:g} s, then up to 3 rounds with nothing new; the channel at "
        f"{args.rate_bps:g} bit/s with {args.loss:g} loss each way, BER {args.ber:g}, {args.duplicate:g} "
        f"duplication, {args.reorder:g} reordering and an outage of {args.outage_s:g} s from "
        f"{args.outage_at_s:g} s. `rounds`: from the link's return (or the restart, if later) until the "
        "replicas' hashes are first equal, in sync rounds (at least 1); `bytes / minimal`: sync bytes that reached "
        "the other agent (both ways, digests and holdings included, channel duplicates not) over the bytes "
        "of the minimal deltas (every published tile version's TILE packet once, its compact tile body "
        "included, and each fresh end's tile profile once; the sync puts a burst's tiles in one packet, so its "
        "tile bytes are below that); `control / minimal`: of the sync bytes, the DIGESTs and HOLDINGS, over the "
        "same; `air / minimal`: every byte put on the air over the same.",
        "",
        markdown_table(summary),
        "",
        "## Runs",
        "",
        markdown_table(rows),
    ])
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "sync.md").write_text(md + "\n")
    print(markdown_table(summary))
    write_results("sync", command_line("sync"), md)
    return 0
