"""``safer-fsw bench executive``: overhead per frame and real-time frame-start lateness."""

from __future__ import annotations

import time

from fsw.executive.executive import Executive
from fsw.framework.clock import MonotonicClock, SteppedClock
from fsw.framework.params import build
from fsw.settings import FswConfig


def noop_config(n_tasks: int = 10, period_s: float = 0.1) -> FswConfig:
    """A schedule of one 10 Hz group with ``n_tasks`` no-op tasks."""
    data = {
        "executive": {
            "frame_period_s": period_s,
            "groups": [{"name": "fast", "divisor": 1, "offset": 0}],
            "tasks": [{"name": f"noop{i}", "kind": "noop", "group": "fast", "budget_ms": 1.0} for i in range(n_tasks)],
        }
    }
    return build(FswConfig, data, source="<bench>")


def bench_executive(frames_overhead: int = 20000, frames_realtime: int = 600) -> int:
    cfg = noop_config()
    exe = Executive(cfg, SteppedClock())
    exe.run_lockstep(200)  # warm up
    t0 = time.perf_counter()
    exe.run_lockstep(frames_overhead)
    per_frame_ms = (time.perf_counter() - t0) / frames_overhead * 1e3
    print(
        f"executive overhead: {per_frame_ms:.4f} ms per frame with 10 no-op tasks "
        f"({frames_overhead} stepped frames; goal <= 0.2 ms)"
    )

    exe_rt = Executive(cfg, MonotonicClock())
    print(
        f"real-time lateness: running {frames_realtime} frames at 10 Hz ({frames_realtime * 0.1:.0f} s) ...", flush=True
    )
    exe_rt.run_realtime(frames_realtime)
    lat = exe_rt.lateness_percentiles_ms()
    print(
        f"frame-start lateness over {frames_realtime} frames: p50 {lat['p50']:.3f} ms, "
        f"p99 {lat['p99']:.3f} ms, max {lat['max']:.3f} ms (goal p99 <= 2 ms); "
        f"slips {exe_rt.slips}, skipped {exe_rt.skipped_frames}"
    )
    return 0
