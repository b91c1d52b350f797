"""The map sync flown by both flight programs in the lockstep team (docs/sync.md, "In flight"):
the RECON-bot's radio task publishes a round per imaging step, the Cliff-bot's one per look, over
the bench's radio beside the map link and the fixes; both replicas end equal, nothing is sent
whole again, and the team section's figures are the flown ends'. The RECON-bot is idle (no
camera) and its map update is a few tiles of the true ground; the Cliff-bot's look is handed
to its radio task as the sensing task would (no rendering): the run is the radio's part."""

from __future__ import annotations

import dataclasses
import json
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from fsw.core.geometry import MapGrid
from fsw.drivers.resources import Resources
from fsw.settings import load_settings
from fsw.tasks.cliffbot.messages import SensedMap
from fsw.tasks.messages import MAP_UPDATED, NBV_REQUEST

SEED = 3
pytestmark = pytest.mark.slow  # two executives on the bench (about 4 s to set up)


def test_both_flight_programs_keep_one_map_in_step() -> None:
    from fsw.comm.team.sync_end import team_figures
    from hil_sim.bench import LockstepBench
    from hil_sim.link.radio_channel import RadioChannel
    from hil_sim.team.team_bench import CliffbotAgent, FixWatch, truth_map
    from hil_sim.world import load_scenario

    world = load_scenario("cliff-team", SEED)
    cfg = load_settings()
    cfg = dataclasses.replace(cfg, map=world.map_grid, mission=dataclasses.replace(cfg.mission, auto_start=False),
                              map_sync=dataclasses.replace(cfg.map_sync, enabled=True))
    grid = MapGrid.from_config(world.map_grid)
    channel = RadioChannel(seed=SEED)
    box: list[Any] = []
    watch = FixWatch(channel, "a", lambda: box[0]() if box else 0.0)
    with LockstepBench(cfg, world, seed=SEED, quiet=True, camera=False, resources=Resources(radio_port=watch)) as b:
        box.append(b.clock.now)
        team = CliffbotAgent(b, world, channel, watch, SEED, 0.0, out=None, recon_done=lambda: False)
        try:
            assert team.cfg.map_sync.enabled  # the bench gives the Cliff-bot the RECON-bot's setting
            z = np.asarray(truth_map(world, grid, team.frame), np.float32)
            mine = np.zeros(z.shape, bool)
            mine[:48, :48] = True  # 9 tiles of the RECON-bot's (those the world reaches)
            b.exe.ctx.bus.publish(MAP_UPDATED, SimpleNamespace(snapshot=SimpleNamespace(z=z, mapped=mine, grid=grid)))
            b.exe.ctx.bus.publish(NBV_REQUEST, None)  # the imaging step ended: its map is a sync round
            radio = team.exe.tasks["cb_radio"]
            own = np.where(~mine, z + 0.01, np.nan)
            own[:, 80:] = np.nan
            own[64:] = np.nan  # its look: 11 more tiles, its own
            radio._own_round(SensedMap(1, z, 0.03, 1, int(np.isfinite(own).sum()), own))  # type: ignore[attr-defined]
            for _ in range(400):
                b.run(1)
                if b.clock.now() > 5.0 and team.sync_settled():
                    break
            recon, cliff = team._sync("radio"), team._sync("cb_radio")
            assert recon is not None and cliff is not None and team.sync_settled()
            figs = json.loads(json.dumps(team_figures(recon, cliff)))  # what summary.json holds
            assert figs["sync_source"] == "flown" and figs["sync_hash_equal"] is True
            assert figs["sync_rounds"] == 2 and figs["sync_full_resends"] == 0
            def tiles(m: np.ndarray) -> int:
                return int(np.isfinite(m).reshape(m.shape[0] // 16, 16, m.shape[1] // 16, 16).any(axis=(1, 3)).sum())

            assert [e["tiles_published"] for e in figs["sync_ends"]] == [tiles(np.where(mine, z, np.nan)), tiles(own)]
            assert figs["sync_ends"][1]["tiles_published"] > 5
            # (a round's tiles share TILEs: the bytes may be below the minimal deltas, one tile a packet)
            assert figs["sync_minimal_bytes"] > 0 and 0 < figs["sync_bytes"] <= figs["sync_air_bytes"]
            # each holds the other's layer as the other made it: the RECON-bot's tiles within the bound
            held = cliff.end.replica_map(0)
            assert np.nanmax(np.abs(held[:48, :48] - z[:48, :48])) <= recon.bound_m + 1e-6
            assert np.isfinite(recon.end.replica_map(1)).sum() == np.isfinite(own).sum()
            st = team.state()  # the team's part of a RECON-bot checkpoint holds the Cliff-bot's end
            assert st["sync"]["boot"] == 0 and json.loads(st["sync"]["sync"])["agent"] == 1
            assert "sync" in b.exe.tasks["radio"].checkpoint_state()  # type: ignore[attr-defined]
        finally:
            team.close()
