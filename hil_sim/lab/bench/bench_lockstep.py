"""``safer-hil bench lockstep``: how much faster than real time the lockstep bench runs.

Drives the rover back and forth along the plateau and sweeps the mast through the flight
drivers (CAN ``virtual`` bus, in-memory serial pair) for ``--seconds`` of bench time, with
and without a stereo capture every ``--capture-period`` seconds, and prints bench seconds per
wall second, the wall time per frame split into hardware rig and flight executive, and the
CAN frame rate.
"""

from __future__ import annotations

import argparse
import sys
import time

HELP = "lockstep bench speed against real time (rig + flight executive, optional captures)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default="lab", help="world (hil_sim.world.load_scenario spec)")
    p.add_argument("--seed", type=int, default=0, help="seed of world, truth and faults")
    p.add_argument("--seconds", type=float, default=60.0, help="bench seconds per run")
    p.add_argument(
        "--capture-period",
        type=float,
        default=5.0,
        metavar="S",
        help="seconds between stereo captures in the second run (0: skip that run)",
    )
    p.add_argument("--config", default=None, help="flight configuration (default config/fsw.toml)")


def _run(cfg, world, seed: int, seconds: float, capture_period: float) -> dict[str, float]:
    from hil_sim.bench import LockstepBench

    with LockstepBench(cfg, world, seed=seed, camera=capture_period > 0, quiet=True) as b:
        b.run(3)
        frames = round(seconds / b.exe.period_s)
        t_rig = t_exe = 0.0
        leg, pan = 1.0, 40.0
        next_capture = capture_period
        for _ in range(frames):
            if b.tlm("motion.state") == "IDLE":
                b.command("motion.DRIVE", distance_m=leg, speed_mps=0.0)
                leg = -leg
            if not b.tlm("motion.mast_busy"):
                b.command("motion.POINT_MAST", pan_deg=pan, tilt_deg=-30.0, lift_m=0.3)
                pan = -pan
            cam = b.exe.ctx.res.camera
            if cam is not None and b.clock.now() >= next_capture:
                cam.trigger(b.clock.now())
                next_capture += capture_period
            t0 = time.perf_counter()
            b.clock.sleep_until(b.exe.frame_start(b.exe.frame))
            b.before_frame(b.exe.frame)
            t1 = time.perf_counter()
            b.exe.step()
            t2 = time.perf_counter()
            t_rig += t1 - t0
            t_exe += t2 - t1
        wall = t_rig + t_exe
        return {
            "frames": frames,
            "bench_s": frames * b.exe.period_s,
            "wall_s": wall,
            "rig_ms": t_rig / frames * 1e3,
            "exe_ms": t_exe / frames * 1e3,
            "can_fps": (b.rig.motors.tx_frames + b.rig.motors.rx_commands) / (frames * b.exe.period_s),
            "pairs": b.camera.rendered if b.camera is not None else 0,
            "path_m": b.rig.rover.odometer_m,
        }


def run(args: argparse.Namespace) -> int:
    from fsw.framework.params import ConfigError
    from fsw.settings import DEFAULT_CONFIG, load_settings
    from hil_sim.world import load_scenario

    if args.seconds <= 0 or args.capture_period < 0:
        print("safer-hil bench lockstep: --seconds must be > 0 and --capture-period >= 0", file=sys.stderr)
        return 2
    try:
        cfg = load_settings(args.config or DEFAULT_CONFIG)
        world = load_scenario(args.scenario, args.seed)
    except (ConfigError, ValueError) as err:
        print(f"safer-hil bench lockstep: {err}", file=sys.stderr)
        return 2
    runs = [("no captures", 0.0)] + (
        [(f"a {cfg.camera.width_px}x{cfg.camera.height_px} pair every {args.capture_period:g} s", args.capture_period)]
        if args.capture_period
        else []
    )
    for label, period in runs:
        r = _run(cfg, world, args.seed, args.seconds, period)
        print(
            f"lockstep, {label}: {r['bench_s']:.0f} bench s in {r['wall_s']:.2f} wall s = "
            f"{r['bench_s'] / r['wall_s']:.1f}x real time; per {cfg.executive.frame_period_s * 1e3:.0f} ms frame: "
            f"rig {r['rig_ms']:.2f} ms, flight executive {r['exe_ms']:.2f} ms; CAN {r['can_fps']:.0f} frames/s; "
            f"{r['pairs']} pairs rendered; rover drove {r['path_m']:.2f} m"
        )
    return 0
