"""The ground link's view (issue 15, a lean foreground): the view hands the downlink its
channel table and the store's change set, and the scheduler chooses from them the same
channels in the same order as ranking every channel (stepped clock, values that change,
repeat, go NaN, leave their limits), while reading only a few of them a frame."""

from __future__ import annotations

import math
import random
from types import SimpleNamespace

import pytest

from fsw.comm.mavlink_config import MavlinkConfig
from fsw.comm.mavlink_downlink import ChannelScheduler, ChannelTable
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


class _CountingCell:
    """A store cell that counts how often its value is read."""

    def __init__(self, cell: object) -> None:
        self.cell, self.reads = cell, 0

    @property
    def value(self) -> object:
        self.reads += 1
        return self.cell.value  # type: ignore[attr-defined]


@pytest.mark.parametrize("rates", [None, (0.35, 2.05), (0.1, 0.3)])
def test_lazy_ranking_gives_the_same_choice_as_ranking_every_channel(rates: tuple[float, float] | None) -> None:
    cfg = MavlinkConfig() if rates is None else MavlinkConfig(channel_period_s=rates[0], channel_refresh_s=rates[1])
    ctx = _context(190)
    store = ctx.telemetry
    view = ViewBuilder(ctx, cfg, _box())  # type: ignore[arg-type]
    table = view.channels
    counted = ChannelTable(tuple((k, _CountingCell(c), lo, hi) for k, c, lo, hi in table.rows), table.changed)
    lazy = ChannelScheduler(cfg.channel_period_s, cfg.channel_refresh_s)
    full = ChannelScheduler(cfg.channel_period_s, cfg.channel_refresh_s)
    rng = random.Random(7)
    names = list(store.values)
    urgent = reads = 0
    for k in range(400):
        now = k * FRAME_S
        for i, name in enumerate(names):  # a tenth change every frame, the rest rarely; NaN, None, text
            r = rng.random() * (1.0 if i % 10 else 0.1)
            if r < 0.02:
                store.write(name, rng.uniform(-8.0, 8.0), now)
            elif r < 0.025:
                store.write(name, math.nan, now)
            elif r < 0.03:
                store.write(name, rng.choice([None, "text", 3, True]), now)
            elif r < 0.06:
                store.write(name, store.values[name].value, now)  # written again, unchanged
        view.build(now)  # takes the store's change set into the table
        expected = full.due(now, counted.samples())
        urgent += sum(s.out_of_limits for s in expected)
        before = sum(c.reads for c in _cells(counted))
        got = lazy.ranked(now, counted)
        reads += sum(c.reads for c in _cells(counted)) - before
        assert [(s.key, s.out_of_limits) for s in got] == [(s.key, s.out_of_limits) for s in expected]
        sent = rng.randint(0, 20)  # what a byte budget lets through this frame
        for s in got[:sent]:
            lazy.mark(now, s)
            full.mark(now, s)
        assert _same(lazy.last, full.last)
    assert urgent > 0  # the test exercised channels out of their limits
    if rates is None:  # the point, at the flight rates: few channels are read a frame
        assert reads < 0.25 * 400 * len(counted.rows)


def _cells(table: ChannelTable) -> list[_CountingCell]:
    return [c for _, c, _, _ in table.rows]  # type: ignore[misc]


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
