"""Issue 28 item 3's done-when on a stepped clock (hil_sim.team.team_sync; docs/sync.md).

Through the hostile channel (30 % loss each way, BER 3e-5, 10 % duplication and reordering,
a 60 s outage) and a SIGKILL + restart of either agent from its checkpoint, both replicas reach
the same hash within 3 sync rounds of the link's return (or the restart), with at most 1.2x
the bytes of the minimal deltas in every run, and no full resend. Scenes of 128 x 128 cells
(64 tiles) and 16 rounds, as the experiment's but shorter, so a run takes about a second; the
30-seed figures are ``safer-hil experiment sync``'s (docs/results/sync.md).

Bytes: the minimal deltas count each published tile version once in a packet of its own
(docs/sync.md, "Figures"); the sync puts the tiles of a burst in one TILE, so its tile bytes
are below them and the DIGESTs and HOLDINGS are what the rest pays for.
"""

from __future__ import annotations

import numpy as np
import pytest

from hil_sim.link.radio_channel import RadioChannelConfig
from hil_sim.team.team_sync import Kill, SyncResult, make_scene, run_sync, sync_figures, team_sync_figures

OUTAGE = (40.0, 60.0)
BACK = OUTAGE[0] + OUTAGE[1]
HOSTILE = RadioChannelConfig(loss=0.3, ber=3e-5, duplicate=0.1, reorder=0.1, outages=(OUTAGE,))
WORST_RATIO = 1.2  # sync bytes over the minimal deltas, every run


def run(seed: int, kills: tuple[Kill, ...] = ()) -> SyncResult:
    return run_sync(make_scene(seed, n=128, rounds=16, radius=20), HOSTILE, seed, kills=kills)


def check(res: SyncResult, since_s: float) -> float:
    """The done-when for one run; returns its sync bytes over the minimal deltas."""
    assert res.hash_equal
    rounds = res.rounds_to_equal_after(since_s)
    assert rounds is not None and rounds <= 3, res.equal_times_s
    assert res.sync_bytes <= WORST_RATIO * res.minimal_bytes, (res.sync_bytes, res.minimal_bytes)
    assert res.full_resends == 0
    # The channel really was hostile: duplicated packets arrived, tiles were lost and sent again.
    assert sum(s.dup_packets for s in res.stats.values()) > 0
    assert sum(s.resent_tiles for s in res.stats.values()) > 0
    return res.sync_bytes / res.minimal_bytes


def test_replicas_converge_after_a_60_s_outage() -> None:
    res = run(1)
    check(res, BACK)
    figs = sync_figures(res)
    assert figs["sync_hash_equal"] is True and figs["sync_full_resends"] == 0
    assert figs["sync_rounds"] == res.rounds and figs["sync_minimal_bytes"] == res.minimal_bytes


def test_the_recon_bot_killed_in_the_outage_catches_up_from_its_checkpoint() -> None:
    res = run(2, (Kill(0, 60.0, 10.0),))
    check(res, BACK)
    assert res.stats[1].peer_restarts == 1
    assert any(e[0] == 0 and e[2] == "HOLDINGS" and e[1] > 70.0 for e in res.events)


def test_the_cliff_bot_killed_after_the_outage_gets_back_what_it_lost() -> None:
    kill = Kill(1, 145.0, 5.0)  # its last checkpoint was at 120 s, rounds 130 and 140 are lost
    res = run(3, (kill,))
    check(res, kill.at_s + kill.down_s)
    # It had published tiles after its last checkpoint: the RECON-bot gives them back.
    assert res.stats[1].adopted > 0 and res.stats[0].returns_out >= res.stats[1].adopted


def test_a_lost_replica_is_the_one_full_resend() -> None:
    kill = Kill(1, 145.0, 5.0, from_checkpoint=False)
    res = run(0, (kill,))
    assert res.hash_equal and res.full_resends == 1
    assert res.stats[0].full_resends == 1 and res.stats[1].adopted > 0


def test_a_seeded_run_is_repeatable() -> None:
    def small() -> SyncResult:
        return run_sync(make_scene(3, n=64, rounds=12, radius=12), HOSTILE, 3, kills=(Kill(0, 60.0, 10.0),))

    a, b = small(), small()
    assert sync_figures(a) == sync_figures(b) and a.equal_times_s == b.equal_times_s


@pytest.mark.slow
def test_more_seeds_through_outage_and_restarts() -> None:
    for seed in range(4, 10):
        check(run(seed), BACK)
        check(run(seed, (Kill(0, 60.0, 10.0),)), BACK)
        check(run(seed, (Kill(1, 145.0, 5.0),)), 150.0)


def test_the_team_mission_hands_its_maps_per_cycle() -> None:
    scene = make_scene(5, n=48, rounds=4, radius=10)
    maps = []
    for agent in (0, 1):  # each agent's map after each cycle: what it saw so far
        seen, z, out = scene.truth.copy(), None, []
        for r in range(scene.rounds):
            cy, cx = scene.views[agent][r]
            yy, xx = np.mgrid[:48, :48]
            disc = (yy - cy) ** 2 + (xx - cx) ** 2 <= 100
            z = np.where(disc, seen, np.nan) if z is None else np.where(disc, seen, z)
            out.append(z.astype(np.float32))
        maps.append(out)
    figs = team_sync_figures(maps[0], maps[1], RadioChannelConfig(loss=0.1), 0, cell_m=0.03, wheel_m=0.2)
    assert figs["sync_hash_equal"] is True and figs["sync_rounds"] == 4 and figs["sync_full_resends"] == 0
    minimal, sent = figs["sync_minimal_bytes"], figs["sync_bytes"]
    assert isinstance(minimal, int) and isinstance(sent, int) and minimal > 0 and sent <= 1.5 * minimal
    with pytest.raises(ValueError, match="every cycle"):
        team_sync_figures(maps[0], maps[1][:2], RadioChannelConfig(), 0, cell_m=0.03, wheel_m=0.2)
