"""``safer-ground plot LOG.tlog --out DIR``: PNG plots of a flight software run.

Writes whatever the log supports: ``task_timing.png`` (execution time per task against its
budget), ``slips.png`` (slips per rate group, overruns per task), ``mapped_cells.png``
(channels whose name contains ``mapped``), ``link.png`` (downlink wire rate and goodput =
payload bytes, uplink rate, downlink bytes by message type) and ``channels.png`` (small
multiples of the other channels that changed). Time is seconds from the first record.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

from ground.dictionary import GroundDictionary

HELP = "PNG plots from a .tlog: task timing, slips, mapped cells, link goodput, channels"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("tlog", metavar="LOG.tlog", help="telemetry log written by the flight software or a GCS")
    p.add_argument("--out", required=True, metavar="DIR", help="directory for the PNG files (created)")
    p.add_argument("--max-channels", type=int, default=24, help="panels in channels.png")


def collect(messages: list[Any], d: GroundDictionary) -> dict[str, Any]:
    """Series from logged messages: channels, link bytes per second, the rover's id."""
    from fsw.comm.mavlink_dialect import mavlink
    from fsw.comm.mavlink_telemetry import DICT_CRC_KEY

    t0 = messages[0].time_s
    rover = next((m.msg.get_srcSystem() for m in messages
                  if m.msg.get_type() == "HEARTBEAT" and m.msg.type != mavlink.MAV_TYPE_GCS), None)
    remote_crc = next((int(m.msg.value) for m in messages if m.msg.get_type() == "NAMED_VALUE_INT"
                       and _text(m.msg.name) == DICT_CRC_KEY), None)
    series: dict[str, list[tuple[float, float]]] = defaultdict(list)
    wire: dict[str, dict[int, int]] = {"down": defaultdict(int), "up": defaultdict(int), "good": defaultdict(int)}
    by_type: dict[str, dict[int, int]] = defaultdict(lambda: defaultdict(int))
    for lm in messages:
        t, msg = lm.time_s - t0, lm.msg
        sec = int(t)
        down = msg.get_srcSystem() == rover
        wire["down" if down else "up"][sec] += len(lm.frame)
        if down:
            hdr = msg.get_header()
            wire["good"][sec] += hdr.mlen
            by_type[msg.get_type()][sec] += len(lm.frame)
        kind = msg.get_type()
        if down and kind in ("NAMED_VALUE_FLOAT", "NAMED_VALUE_INT") and _text(msg.name) != DICT_CRC_KEY:
            series[d.channel_name(_text(msg.name), remote_crc)].append((t, float(msg.value)))
    duration = messages[-1].time_s - t0
    return {"series": dict(series), "wire": wire, "by_type": dict(by_type), "duration": duration,
            "crc_ok": remote_crc is None or remote_crc == d.crc, "rover": rover}


def _text(v: Any) -> str:
    return v.decode("utf-8", "replace") if isinstance(v, bytes) else str(v)


def _grid(n: int) -> tuple[int, int]:
    cols = min(4, max(1, n))
    return math.ceil(n / cols), cols


def plot_all(data: dict[str, Any], d: GroundDictionary, out: Path, max_channels: int) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written: list[str] = []
    series = data["series"]

    def save(fig: Any, name: str) -> None:
        fig.tight_layout()
        fig.savefig(out / name, dpi=90)
        plt.close(fig)
        written.append(str(out / name))

    timing = [t for t in d.budgets_ms if f"{t}.exec_last_ms" in series]
    if timing:
        rows, cols = _grid(len(timing))
        fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 2.6 * rows), squeeze=False)
        for ax, task in zip(axes.flat, timing, strict=False):
            ts, vs = zip(*series[f"{task}.exec_last_ms"], strict=True)
            ax.plot(ts, vs, lw=0.8, label="last")
            if f"{task}.exec_max_ms" in series:
                tm, vm = zip(*series[f"{task}.exec_max_ms"], strict=True)
                ax.plot(tm, vm, lw=0.8, ls=":", label="max")
            ax.axhline(d.budgets_ms[task], color="r", ls="--", lw=0.8, label="budget")
            ax.set_title(task, fontsize=9)
            ax.set_ylabel("ms")
            ax.set_xlabel("s")
        for ax in list(axes.flat)[len(timing):]:
            ax.axis("off")
        axes.flat[0].legend(fontsize=7)
        save(fig, "task_timing.png")
    slip_names = [n for n in series if n.endswith(".slips")]
    ovr_names = [n for n in series if n.endswith(".overruns")]
    if slip_names or ovr_names:
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.2))
        for n in sorted(slip_names):
            ts, vs = zip(*series[n], strict=True)
            a1.step(ts, vs, where="post", label=n)
        for n in sorted(ovr_names):
            ts, vs = zip(*series[n], strict=True)
            a2.step(ts, vs, where="post", label=n)
        a1.set_title("slips (cumulative)")
        a2.set_title("overruns per task (cumulative)")
        for a in (a1, a2):
            a.set_xlabel("s")
            if a.lines:
                a.legend(fontsize=6)
        save(fig, "slips.png")
    mapped = [n for n in series if "mapped" in n]
    if mapped:
        fig, ax = plt.subplots(figsize=(6, 3.2))
        for n in mapped:
            ts, vs = zip(*series[n], strict=True)
            ax.plot(ts, vs, label=n)
        ax.set_xlabel("s")
        ax.set_ylabel("cells")
        ax.set_title("mapped cells")
        ax.legend(fontsize=7)
        save(fig, "mapped_cells.png")
    wire = data["wire"]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.4))
    secs = range(int(data["duration"]) + 1)
    for key, label in (("down", "downlink wire"), ("good", "downlink goodput (payload)"), ("up", "uplink wire")):
        a1.plot(list(secs), [8 * wire[key].get(s, 0) / 1000 for s in secs], label=label)
    a1.set_xlabel("s")
    a1.set_ylabel("kbit/s")
    a1.set_title("link rate (1 s bins)")
    a1.legend(fontsize=7)
    top = sorted(data["by_type"], key=lambda k: -sum(data["by_type"][k].values()))[:8]
    if top:
        a2.stackplot(list(secs), [[8 * data["by_type"][k].get(s, 0) / 1000 for s in secs] for k in top], labels=top)
        a2.legend(fontsize=6, loc="upper left")
    a2.set_xlabel("s")
    a2.set_ylabel("kbit/s")
    a2.set_title("downlink by message type")
    save(fig, "link.png")
    others = [n for n in sorted(series) if n not in mapped and not n.endswith(("exec_last_ms", "exec_max_ms"))
              and len({v for _, v in series[n]}) > 1][:max_channels]
    if others:
        rows, cols = _grid(len(others))
        fig, axes = plt.subplots(rows, cols, figsize=(3.4 * cols, 2.2 * rows), squeeze=False)
        for ax, n in zip(axes.flat, others, strict=False):
            ts, vs = zip(*series[n], strict=True)
            ax.plot(ts, vs, lw=0.8)
            ax.set_title(n, fontsize=8)
            ax.tick_params(labelsize=7)
        for ax in list(axes.flat)[len(others):]:
            ax.axis("off")
        save(fig, "channels.png")
    return written


def run(args: argparse.Namespace, d: GroundDictionary) -> int:
    from fsw.comm.mavlink_tlog import TlogError
    from ground.tlog import load_messages

    if args.max_channels < 0:
        print("safer-ground plot: --max-channels must be >= 0", file=sys.stderr)
        return 2
    try:
        messages, note = load_messages(args.tlog)
    except TlogError as exc:
        print(f"safer-ground plot: {exc}", file=sys.stderr)
        return 2
    if note:
        print(f"safer-ground plot: warning: {note}", file=sys.stderr)
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(f"safer-ground plot: cannot create {out}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    data = collect(messages, d)
    if not data["crc_ok"]:
        print(f"safer-ground plot: warning: the log's dictionary differs from {d.source}; raw keys used",
              file=sys.stderr)
    for path in plot_all(data, d, out, args.max_channels):
        print(path)
    print(f"{len(messages)} messages over {data['duration']:.1f} s, {len(data['series'])} channels")
    return 0
