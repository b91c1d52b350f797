"""The batched tether statics (fsw.core.team.tether_batch, tether_states, statics_many, settle)
give the one-at-a-time code's results bit for bit, on random places, profiles and lengths
(the reference is the code as first written: tests/support/tether_reference.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import tether_reference as ref

from fsw.core.geometry import MapGrid
from fsw.core.team.tether import TetherConfig, TetherState, anchor_points, statics, statics_many, tether_state
from fsw.core.team.tether import tether_states as batched_states
from fsw.core.team.tether_batch import upper_hulls
from fsw.core.team.tether_settle import settle


def rough_cliff(seed: int) -> tuple[np.ndarray, MapGrid]:
    """A plateau, a rough 70-80 deg face with a ledge and a floor, with holes of unknown ground."""
    rng = np.random.default_rng(seed)
    grid = MapGrid(-2.0, -2.5, 0.05, 80, 72)
    x, y = grid.centers()
    face = np.maximum(math.tan(math.radians(rng.uniform(70, 80))) * y, -2.0)
    z = np.where(y > 0, 0.0, face) + 0.03 * rng.standard_normal(grid.shape)
    z[(np.abs(y + 0.8) < 0.1) & (x > 0)] += 0.2  # a ledge
    z[(rng.random(grid.shape) < 0.01) & (y < 0.5)] = np.nan  # the anchors' ground stays known
    return z.astype(np.float32), grid


def same(a: TetherState | None, b: TetherState | None) -> bool:
    if a is None or b is None:
        return a is b
    return a.statics == b.statics and all(
        p.length_m == q.length_m and p.unknown == q.unknown and np.array_equal(p.contacts, q.contacts)
        and np.array_equal(p.pull, q.pull) for p, q in zip(a.paths, b.paths, strict=True))


def test_states_match_the_reference_bit_for_bit() -> None:
    cfg = TetherConfig()
    held = 0
    for seed in range(3):
        z, grid = rough_cliff(seed)
        rng = np.random.default_rng(seed)
        anchors = anchor_points(z, grid, np.array([[-1.2, 1.0], [1.1, 0.9]]), cfg)
        xys = rng.uniform([-2.3, -2.8], [2.3, 1.3], size=(120, 2))  # some off the map
        xys[:3] = [[np.nan, 0.0], [0.0, np.inf], [grid.x0 + grid.nx * grid.cell - 1e-9, 0.0]]
        with np.errstate(invalid="ignore"):  # the reference's cast of a NaN place
            want = [ref.tether_state(z, grid, anchors, xy, cfg, 0.3) for xy in xys]
        got = batched_states(z, grid, anchors, xys, cfg, 0.3)
        assert all(same(a, b) for a, b in zip(want, got, strict=True))
        one = [tether_state(z, grid, anchors, xy, cfg, 0.3) for xy in xys[3:40]]
        assert all(same(a, b) for a, b in zip(want[3:40], one, strict=True))
        held += sum(a is not None for a in want)
    assert held > 100  # the comparison covered real tether states, not only Nones


def test_hulls_match_the_reference_on_random_profiles() -> None:
    rng = np.random.default_rng(1)
    runs = [rng.integers(2, 60) for _ in range(40)]
    s = np.concatenate([np.cumsum(rng.uniform(0.01, 0.1, n)) for n in runs])
    h = rng.standard_normal(len(s))
    h[rng.random(len(s)) < 0.1] = -np.inf  # unknown ground
    h[:5] = 1.0  # ties: argmax's first point wins in both
    first = np.cumsum(runs) - runs
    last = first + np.asarray(runs) - 1
    h[first], h[last] = rng.standard_normal(len(runs)), rng.standard_normal(len(runs))  # a tether's ends
    got = upper_hulls(s, h, first, last)
    for f, t, idx in zip(first, last, got, strict=True):
        assert (idx - f).tolist() == ref.upper_hull(s[f:t + 1], h[f:t + 1]).tolist()


def test_statics_many_is_statics_per_row() -> None:
    cfg = TetherConfig()
    rng = np.random.default_rng(2)
    u1, u2, n = (rng.standard_normal((50, 3)) for _ in range(3))
    u2[0] = u1[0]  # degenerate
    rows = statics_many(u1, u2, n, cfg)
    assert rows[0].reason == "degenerate"
    assert rows == [ref.reference_statics(a, b, c, cfg) for a, b, c in zip(u1, u2, n, strict=True)]
    assert rows == [statics(a, b, c, cfg) for a, b, c in zip(u1, u2, n, strict=True)]


def test_settle_matches_the_reference() -> None:
    cfg = TetherConfig()
    z, grid = rough_cliff(0)
    anchors = anchor_points(z, grid, np.array([[-1.2, 1.0], [1.1, 0.9]]), cfg)
    rng = np.random.default_rng(3)
    settled = 0
    for _ in range(8):
        guess = rng.uniform([-0.8, -1.6], [0.8, -0.2])
        st = ref.tether_state(z, grid, anchors, guess, cfg)
        if st is None:
            continue
        lengths = (st.lengths_m[0] + rng.uniform(-0.1, 0.1), st.lengths_m[1] + rng.uniform(-0.1, 0.1))
        want = ref.settle(z, grid, anchors, lengths, guess, cfg)
        got = settle(z, grid, anchors, lengths, guess, cfg)
        assert (want is None) == (got is None)
        if want is not None and got is not None:
            assert np.array_equal(want[0], got[0]) and same(want[1], got[1])
            settled += 1
    assert settled >= 4


def test_batches_in_chunks_and_node_verdicts_match_one_at_a_time(monkeypatch: pytest.MonkeyPatch) -> None:
    """The planner's lattice verdicts (node_reasons, batched) are the one-node-at-a-time verdicts,
    with the batch cut into chunks of a few places."""
    import fsw.core.team.tether as tether_mod
    from fsw.core.team.climber_ground import ClimberConfig
    from fsw.core.team.face_planner import _verdict, node_reasons

    monkeypatch.setattr(tether_mod, "BATCH_PLACES", 7)
    tcfg, ccfg = TetherConfig(), ClimberConfig()
    z, grid = rough_cliff(1)
    anchors = anchor_points(z, grid, np.array([[-1.2, 1.0], [1.1, 0.9]]), tcfg)
    rows, cols, reasons, g = node_reasons(z, grid, anchors, tcfg, ccfg)
    one = [_verdict(z, grid, anchors, tcfg, ccfg, g, int(r), int(c)) for r in rows for c in cols]
    assert reasons == one
    assert len(set(one)) >= 3  # usable, hazard, unknown or a tether reason: the lattice is varied
