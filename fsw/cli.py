"""``safer-fsw``: run the flight software, print its dictionary, calibrate the cameras, benchmark the executive."""

from __future__ import annotations

import argparse
import json
import signal
import sys
from collections.abc import Sequence

from fsw.framework.params import ConfigError
from fsw.settings import DEFAULT_CONFIG, FswConfig, load_settings


def _load(path: str) -> FswConfig | None:
    try:
        return load_settings(path)
    except ConfigError as err:
        print(f"safer-fsw: config error: {err}", file=sys.stderr)
        return None


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt(signal.Signals(signum).name)


def cmd_run(args: argparse.Namespace) -> int:
    from fsw.app import build_executive

    cfg = _load(args.config)
    if cfg is None:
        return 2
    try:
        exe = build_executive(cfg)
    except ConfigError as err:  # e.g. the CAN database named by [devices] can_dbc
        print(f"safer-fsw: config error: {err}", file=sys.stderr)
        return 2
    frames = None if args.duration is None else max(1, round(args.duration / cfg.executive.frame_period_s))
    print(
        f"safer-fsw: agent {cfg.agent.name} ({cfg.agent.kind}, MAVLink system {cfg.mavlink.system_id}): "
        f"running {len(exe.tasks)} components at {1 / exe.period_s:.1f} Hz "
        f"({'until interrupted' if frames is None else f'{frames} frames'}); config {args.config}"
    )
    exe.freeze_heap()  # no full garbage collection walks the start-up heap inside a frame
    # Ctrl-C and a supervisor's SIGTERM stop the executive the same orderly way (drivers closed,
    # queued checkpoint writes finished), even when started with SIGINT ignored (a background job).
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, _interrupt)
    try:
        exe.run_realtime(frames)
    except KeyboardInterrupt:
        print("safer-fsw: interrupted")
    from fsw.drivers.factory import close_devices

    close_devices(exe.ctx.res)  # drivers closed, queued checkpoint writes finished
    lat = exe.lateness_percentiles_ms()
    print(
        f"safer-fsw: {exe.frame} frames, slips {exe.slips}, skipped {exe.skipped_frames}, "
        f"lateness p50 {lat['p50']:.3f} ms p99 {lat['p99']:.3f} ms max {lat['max']:.3f} ms"
    )
    return 0


def cmd_dictionary(args: argparse.Namespace) -> int:
    from fsw.executive.topology import dictionary

    cfg = _load(args.config)
    if cfg is None:
        return 2
    json.dump(dictionary(cfg), sys.stdout, indent=2)
    print()
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from fsw.executive.bench import bench_executive

    return bench_executive(frames_overhead=args.overhead_frames, frames_realtime=args.frames)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="safer-fsw",
        description="MIT-SAFER flight software: runs the agent its configuration names ([agent] kind; "
        "the RECON-bot by default).",
    )
    sub = p.add_subparsers(dest="command", metavar="COMMAND", required=True)
    fmt = argparse.ArgumentDefaultsHelpFormatter

    r = sub.add_parser(
        "run",
        help="run the flight software in real time",
        formatter_class=fmt,
        description="Start the executive and the tasks of the configuration's agent ([agent] name and kind, "
        "the MAVLink system id of [mavlink]) on the real-time clock. A mission found in the "
        "[checkpoint] directory (written after each imaging step) continues at the step where it "
        "stopped; an unusable one is reported as an event and the mission waits for START.",
    )
    r.add_argument("--config", default=str(DEFAULT_CONFIG), help="flight configuration (TOML)")
    r.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="stop after this many seconds (default: run until Ctrl-C)",
    )
    r.set_defaults(_run=cmd_run)

    d = sub.add_parser(
        "dictionary",
        help="print the command/telemetry/event dictionary as JSON",
        formatter_class=fmt,
        description="The ground dictionary, generated from the tasks' declarations.",
    )
    d.add_argument("--config", default=str(DEFAULT_CONFIG), help="flight configuration (TOML)")
    d.set_defaults(_run=cmd_dictionary)

    from fsw.calibrate_cli import add_parser as add_calibrate

    add_calibrate(sub, str(DEFAULT_CONFIG))

    b = sub.add_parser("bench", help="benchmarks", description="Benchmarks that print figures.")
    bsub = b.add_subparsers(dest="what", metavar="WHAT", required=True)
    be = bsub.add_parser(
        "executive", formatter_class=fmt, help="executive overhead per frame and real-time frame-start lateness"
    )
    be.add_argument("--frames", type=int, default=600, help="real-time frames at 10 Hz")
    be.add_argument("--overhead-frames", type=int, default=20000, help="stepped frames for the overhead figure")
    be.set_defaults(_run=cmd_bench)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args._run(args))
    except BrokenPipeError:  # e.g. `safer-fsw dictionary | head`
        return 0


if __name__ == "__main__":
    sys.exit(main())
