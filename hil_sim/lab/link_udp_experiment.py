"""The map link over real sockets: three processes through the impairment relay (docs/algorithm.md §6.6).

One run = ``safer-hil cliffbot`` (the Cliff-bot's receiver), ``safer-hil relay`` (the seeded
channel model on the wall clock, 127.0.0.1 only) and ``safer-hil send-map`` (the RECON-bot's
sender), each its own process, talking UDP on loopback. Every process stops by itself
(close ended, relay idle, timeouts); the driver waits for each with a bound and ends a
straggler by its own process id only.

Figures per run: bit-exact (the Cliff-bot's SHA-256 of what it accepted against the
sender's), time to the verified map, how long after that the sender reported delivered,
and goodput against the capacity left after loss, bit errors and the outage:
``capacity = rate x (1 - loss) x (1 - PER) x (T - outage within T)`` with
``PER = 1 - (1 - BER) ** (8 x DATA packet bytes)``; the same seeds are also run on the
lockstep simulation (``hil_sim.lab.link_sim``) for comparison.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fsw.comm.link import LinkConfig
from fsw.comm.link_packets import DATA_OVERHEAD


@dataclass(frozen=True)
class UdpRunSpec:
    loss: float
    seed: int
    ber: float
    duplicate: float
    reorder: float
    reorder_delay_s: float
    outage: tuple[float, float] | None  # (start_s after the first datagram, duration_s)
    rate_bps: float
    latency_s: float
    payload_bytes: int
    config: str | None
    timeout_s: float
    reverse_loss: float = -1.0  # loss of the Cliff-bot's answers alone (-1: the same as loss)
    linger_s: float = 5.0  # the sender answers FINs until none came for this long
    idle_exit_s: float = 5.0  # the relay stops after this long without a datagram


def _cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "hil_sim.cli", *args]


def _json_lines(text: str) -> list[dict[str, Any]]:
    out = []
    for line in text.splitlines():
        try:
            v = json.loads(line)
        except ValueError:
            continue
        if isinstance(v, dict):
            out.append(v)
    return out


def _first_line(proc: subprocess.Popen[str], name: str, timeout_s: float) -> dict[str, Any]:
    """The first JSON line of a child (it prints its address there), within ``timeout_s``."""
    assert proc.stdout is not None
    import selectors

    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    if not sel.select(timeout_s):
        raise RuntimeError(f"{name} printed nothing within {timeout_s} s")
    line = proc.stdout.readline()
    v = json.loads(line) if line.strip() else {}
    if not isinstance(v, dict):
        raise RuntimeError(f"{name}: unexpected first line {line!r}")
    return v


def _finish(proc: subprocess.Popen[str], timeout_s: float) -> tuple[int, str]:
    """Wait for a child; past ``timeout_s`` end it by its own pid and say so."""
    try:
        out, _ = proc.communicate(timeout=timeout_s)
        return proc.returncode, out
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
        return -9, out


def run_udp(spec: UdpRunSpec) -> dict[str, Any]:
    """One real-socket transfer; returns its row of figures."""
    common = ["--config", spec.config] if spec.config else []
    cb = subprocess.Popen(_cmd("cliffbot", "--listen", "udp://127.0.0.1:0", "--no-decode", "--events",
                               "--rate-bps", str(spec.rate_bps), "--timeout", str(spec.timeout_s),
                               *common), stdout=subprocess.PIPE, text=True)
    procs: list[subprocess.Popen[str]] = [cb]
    try:
        cb_url = _first_line(cb, "cliffbot", 30.0)["listening"]
        relay_args = ["--b-peer", cb_url, "--rate-bps", str(spec.rate_bps), "--latency-s",
                      str(spec.latency_s), "--loss", str(spec.loss), "--ber", str(spec.ber),
                      "--duplicate", str(spec.duplicate), "--reorder", str(spec.reorder),
                      "--reorder-delay-s", str(spec.reorder_delay_s), "--seed", str(spec.seed),
                      "--reverse-loss", str(spec.reverse_loss),
                      "--duration", str(spec.timeout_s), "--idle-exit", str(spec.idle_exit_s)]
        if spec.outage is not None:
            relay_args += ["--outage", str(spec.outage[0]), str(spec.outage[1])]
        relay = subprocess.Popen(_cmd("relay", *relay_args), stdout=subprocess.PIPE, text=True)
        procs.append(relay)
        a_url = _first_line(relay, "relay", 30.0)["a"]
        rover = subprocess.Popen(_cmd("send-map", "--peer", a_url, "--bytes", str(spec.payload_bytes),
                                      "--seed", "0", "--timeout", str(spec.timeout_s),
                                      "--rate-bps", str(spec.rate_bps), "--linger-s", str(spec.linger_s),
                                      *common),
                                 stdout=subprocess.PIPE, text=True)
        procs.append(rover)
        t_begin = time.monotonic()
        rc_rover, out_rover = _finish(rover, spec.timeout_s + 30)
        rc_cb, out_cb = _finish(cb, spec.timeout_s + 30)
        rc_relay, out_relay = _finish(relay, spec.timeout_s + 30)
        wall_s = time.monotonic() - t_begin
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    return _row(spec, _json_lines(out_rover), _json_lines(out_cb), _json_lines(out_relay),
                (rc_rover, rc_cb, rc_relay), wall_s)


def capacity_bps(rate_bps: float, loss: float, ber: float, segment_bytes: int) -> float:
    """Rate left after packet loss and the packet error rate of full DATA packets."""
    per = 1.0 - (1.0 - ber) ** (8 * (segment_bytes + DATA_OVERHEAD))
    return rate_bps * (1.0 - loss) * (1.0 - per)


def _row(spec: UdpRunSpec, rover: list[dict[str, Any]], cb: list[dict[str, Any]],
         relay: list[dict[str, Any]], rcs: tuple[int, int, int], wall_s: float) -> dict[str, Any]:
    start = next((r for r in rover if "started_wall_s" in r), {})
    result = next((r for r in rover if "result" in r), {})
    report = next((r for r in cb if "verified_wall_s" in r), {})
    rel: dict[str, Any] = next((r["relay"] for r in relay if "relay" in r), {})
    closed = next((r for r in cb if r.get("event") == "CLOSED"), {})
    seg = LinkConfig().segment_bytes
    row: dict[str, Any] = {"loss": spec.loss, "reverse_loss": spec.loss if spec.reverse_loss < 0 else spec.reverse_loss,
                           "seed": spec.seed, "bit_exact": False,
                           "verified_s": None, "delivered_lag_s": None, "outage_in_s": 0.0,
                           "goodput_bps": None, "capacity_bps": round(capacity_bps(
                               spec.rate_bps, spec.loss, spec.ber, seg), 1), "ratio": None,
                           "sender": result.get("result", "?"), "close": closed.get("how", "-"),
                           "exit_codes": "/".join(map(str, rcs)), "run_wall_s": round(wall_s, 1),
                           "relay_stopped": rel.get("stopped", "-"),  # "idle" after the traffic, or "duration"
                           "retransmits": result.get("stats", {}).get("retransmits"),
                           "realised_loss": None, "realised_answer_loss": None, "ratio_realised": None}
    if start and report:
        t0, tv = start["started_wall_s"], report["verified_wall_s"]
        row["bit_exact"] = report.get("sha256") == start.get("sha256")
        row["verified_s"] = round(tv - t0, 2)
        if spec.outage is not None and rel:
            o0 = rel["started_wall_s"] + spec.outage[0]
            o1 = o0 + spec.outage[1]
            row["outage_in_s"] = round(max(0.0, min(o1, tv) - max(o0, t0)), 2)
        bits = 8.0 * start["bytes"]
        row["goodput_bps"] = round(bits / (tv - t0), 1)
        row["ratio"] = round(bits / (row["capacity_bps"] * (tv - t0 - row["outage_in_s"])), 4)
        if result.get("delivered_wall_s") is not None:
            row["delivered_lag_s"] = round(result["delivered_wall_s"] - tv, 2)
    if rel:
        a, b = rel["a_to_b"], rel["b_to_a"]
        row["realised_loss"] = round(a["lost"] / max(1, a["sent"] - a["outage_drops"] - a["queue_drops"]), 3)
        row["realised_answer_loss"] = round(b["lost"] / max(1, b["sent"] - b["outage_drops"] - b["queue_drops"]), 3)
        if row["ratio"] is not None and row["realised_loss"] < 1:
            # against the capacity the channel really left (its own loss draws, not the nominal)
            row["ratio_realised"] = round(row["ratio"] * (1 - spec.loss) / (1 - row["realised_loss"]), 4)
    return row


def sim_ratio(spec: UdpRunSpec, link: LinkConfig, data: bytes) -> float:
    """The same impairments on the lockstep simulation (outage from the transfer's start)."""
    from hil_sim.lab.link_sim import run_transfer
    from hil_sim.link.radio_channel import RadioChannelConfig

    ch = RadioChannelConfig(rate_bps=spec.rate_bps, latency_s=spec.latency_s, loss=spec.loss,
                            reverse_loss=spec.reverse_loss, ber=spec.ber, duplicate=spec.duplicate,
                            reorder=spec.reorder, reorder_delay_s=spec.reorder_delay_s,
                            outages=(spec.outage,) if spec.outage else ())
    r = run_transfer(data, link, ch, seed=spec.seed)
    if r.delivered != data or not r.delivered_s:
        return 0.0
    out_in = 0.0
    if spec.outage:
        out_in = max(0.0, min(spec.outage[0] + spec.outage[1], r.delivered_s) - spec.outage[0])
    cap = capacity_bps(spec.rate_bps, spec.loss, spec.ber, link.segment_bytes)
    return 8.0 * len(data) / (cap * (r.delivered_s - out_in))


def run_all(specs: list[UdpRunSpec], jobs: int) -> list[dict[str, Any]]:
    """Run the transfers, ``jobs`` at a time (each on its own ports), in spec order."""
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        futures = [pool.submit(run_udp, s) for s in specs]
        rows = []
        for s, f in zip(specs, futures, strict=True):
            row = f.result()
            print(f"udp loss={s.loss:g} seed={s.seed}: bit-exact {row['bit_exact']}, verified in "
                  f"{row['verified_s']} s, sender +{row['delivered_lag_s']} s, ratio {row['ratio']}, "
                  f"close {row['close']}, exits {row['exit_codes']}", flush=True)
            rows.append(row)
    return rows


def write_tables(rows: list[dict[str, Any]], out: Path, header: str) -> str:
    """``udp_runs.csv`` and ``udp_report.md`` (per run, then medians per loss)."""
    import csv

    import numpy as np

    out.mkdir(parents=True, exist_ok=True)
    with (out / "udp_runs.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    cols = ["loss", "reverse_loss", "seed", "bit_exact", "verified_s", "delivered_lag_s", "outage_in_s",
            "goodput_bps", "capacity_bps", "ratio", "sim_ratio", "realised_loss", "realised_answer_loss",
            "ratio_realised", "retransmits", "close", "exit_codes", "run_wall_s"]
    lines = [header, "", "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(str(r.get(c, "")) for c in cols) + " |" for r in rows]
    lines += ["", "| loss | answers lost | runs | bit-exact | median ratio | min ratio | median sim ratio "
              "| max sender lag s |", "|---|---|---|---|---|---|---|---|"]
    for loss, back in sorted({(r["loss"], r["reverse_loss"]) for r in rows}):
        sel = [r for r in rows if (r["loss"], r["reverse_loss"]) == (loss, back)]
        ratios = [r["ratio"] or 0.0 for r in sel]
        lags = [r["delivered_lag_s"] for r in sel if r["delivered_lag_s"] is not None]
        sims = [r.get("sim_ratio") or 0.0 for r in sel]
        lines.append(f"| {loss:g} | {back:g} | {len(sel)} | {sum(bool(r['bit_exact']) for r in sel)}/{len(sel)} "
                     f"| {np.median(ratios):.3f} | {min(ratios):.3f} | {np.median(sims):.3f} "
                     f"| {max(lags) if len(lags) == len(sel) else 'missing'} |")
    text = "\n".join(lines) + "\n"
    (out / "udp_report.md").write_text(text)
    return text
