"""The ground link's view (issue 15, a lean foreground): given the channel scheduler, the view
offers only the channels the scheduler may send now, and the scheduler's choice is the same
as when every channel is offered (stepped clock, values that change, repeat, go NaN)."""

from __future__ import annotations

import math
import random
from types import SimpleNamespace

from fsw.comm.mavlink_config import MavlinkConfig
from fsw.comm.mavlink_downlink import ChannelScheduler
from fsw.framework.bus import Mailbox
from fsw.framework.telemetry import Channel, TelemetryStore
from fsw.tasks.mavlink_view import ViewBuilder

FRAME_S = 0.1


def _context(n: int) -> SimpleNamespace:
    store = TelemetryStore()
    for i in range(n):
        store.register(f"t{i % 7}.c{i}", Channel(f"c{i}", lo=-5.0 if i % 3 == 0 else None, hi=5.0 if i % 4 else None))
    runtime = SimpleNamespace(busy_s=lambda frame: 0.0, period_s=FRAME_S, slips=0, tasks={})
    clock = SimpleNamespace(realtime=False)
    return SimpleNamespace(telemetry=store, runtime=runtime, frame=0, clock=clock)


def _box() -> Mailbox[object]:
    return Mailbox("nav.pose", 1, "drop_oldest")


def test_prefiltered_view_gives_the_scheduler_the_same_choice() -> None:
    cfg = MavlinkConfig()
    ctx = _context(190)
    fast_sched = ChannelScheduler(cfg.channel_period_s, cfg.channel_refresh_s)
    full_sched = ChannelScheduler(cfg.channel_period_s, cfg.channel_refresh_s)
    fast = ViewBuilder(ctx, cfg, _box(), fast_sched)  # type: ignore[arg-type]
    full = ViewBuilder(ctx, cfg, _box())  # type: ignore[arg-type]
    rng = random.Random(7)
    cells = list(ctx.telemetry.values.values())
    offered_fast = offered_full = 0
    for k in range(400):
        now = k * FRAME_S
        for cv in cells:  # some channels change every frame, most rarely, a few go NaN, None or text
            r = rng.random()
            if r < 0.15:
                cv.value = rng.uniform(-8.0, 8.0)
            elif r < 0.17:
                cv.value = math.nan
            elif r < 0.18:
                cv.value = rng.choice([None, "text", 3, True])
        a, b = fast.build(now).channels, full.build(now).channels
        offered_fast, offered_full = offered_fast + len(a), offered_full + len(b)
        due_a, due_b = fast_sched.due(now, a), full_sched.due(now, b)
        assert [s.key for s in due_a] == [s.key for s in due_b]
        sent = rng.randint(0, 20)  # what a byte budget lets through this frame
        for s in due_a[:sent]:
            fast_sched.mark(now, s)
        for s in due_b[:sent]:
            full_sched.mark(now, s)
        assert _same(fast_sched.last, full_sched.last)
    assert offered_fast < 0.6 * offered_full  # the point: channels the scheduler would skip are not offered


def _same(a: dict, b: dict) -> bool:
    if a.keys() != b.keys():
        return False
    for key, (t, v) in a.items():
        t2, v2 = b[key]
        both_nan = isinstance(v, float) and isinstance(v2, float) and math.isnan(v) and math.isnan(v2)
        if t != t2 or not (v == v2 or both_nan):
            return False
    return True


def test_same_value_semantics() -> None:
    import numpy as np

    from fsw.comm.mavlink_downlink import same_value

    assert same_value(1, 1.0) and same_value(math.nan, math.nan) and same_value(np.float64("nan"), math.nan)
    assert not same_value(1.0, 2.0) and not same_value(math.nan, 1.0) and not same_value(0, math.nan)
    assert not same_value(np.zeros(2), np.zeros(2))  # cannot compare to one truth value: differs
    assert same_value(np.int64(3), 3) and not same_value(True, 2)
