"""Issue 29, done-when 3: both agents of a team mission are two MAVLink systems and two sources of
the mission's recording. The Cliff-bot's executive (system 2) beside an idle RECON-bot (system 1)
that hands it the true ground as its map, as in test_cliffbot_agent.py; the recording's Cliff-bot
source is fed by :class:`ground.recording.CliffbotTap`, the one ``safer-hil run`` adds for a team."""

from __future__ import annotations

import dataclasses
from collections import defaultdict
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from fsw.comm.mavlink_telemetry import mode_name
from fsw.core.geometry import MapGrid
from fsw.drivers.resources import Resources
from fsw.settings import load_settings
from fsw.tasks.messages import RADIO_SEND, RadioSendRequest
from ground.tlog import load_messages

SEED = 3


@pytest.mark.slow
def test_the_cliffbot_is_system_2_and_a_source_of_the_recording(tmp_path: Path) -> None:
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    from ground.recording import BusTap, CliffbotTap, MissionRecorder
    from hil_sim.bench import LockstepBench
    from hil_sim.link.radio_channel import RadioChannel
    from hil_sim.team.team_bench import CliffbotAgent, FixWatch, truth_map
    from hil_sim.world import load_scenario

    world = load_scenario("cliff-team", SEED)
    cfg = load_settings()
    cfg = dataclasses.replace(cfg, map=world.map_grid, mission=dataclasses.replace(cfg.mission, auto_start=False))
    grid = MapGrid.from_config(world.map_grid)
    channel = RadioChannel(seed=SEED)
    box: list[Any] = []
    watch = FixWatch(channel, "a", lambda: box[0]() if box else 0.0)
    rec = MissionRecorder(tmp_path / "mission.mcap")
    with LockstepBench(cfg, world, seed=SEED, quiet=True, camera=False, resources=Resources(radio_port=watch)) as b:
        box.append(b.clock.now)
        team = CliffbotAgent(b, world, channel, watch, SEED, 0.0, out=tmp_path, recon_done=lambda: False)
        taps = [BusTap(b.exe, rec.source("recon")), CliffbotTap(team.exe, rec.source("cliffbot"))]
        try:
            z = np.asarray(truth_map(world, grid, team.frame), np.float32)
            b.exe.ctx.bus.publish(RADIO_SEND, RadioSendRequest(1, SimpleNamespace(z=z, grid=grid)))  # type: ignore[arg-type]
            for _ in range(600):  # the map down the link (about 8 kB at 9600 bit/s), its 16 views, the plan, the moves
                b.run(1)
                for tap in taps:
                    tap.poll()
            got_map = team.mission.z
        finally:
            for tap in taps:
                tap.close()
            rec.close()
            t_end = b.clock.now()
            team.close()  # closes cliffbot.tlog too
    assert got_map is not None
    topics: dict[str, list[Any]] = defaultdict(list)
    with (tmp_path / "mission.mcap").open("rb") as fh:
        for _s, ch, _m, msg in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            topics[ch.topic].append(msg)
    grids = topics["/cliffbot/map/elevation"]
    assert len(grids) == 1 and grids[0].column_count == grid.nx
    cells = np.frombuffer(grids[0].data, "<f4").reshape(grid.ny, grid.nx)
    assert np.array_equal(np.isnan(cells), np.isnan(got_map))  # the map the Cliff-bot received, as it holds it
    # (the ground under its body it knows by contact: fsw.core.team.contact_ground)
    x, y = grid.centers()
    sx, sy = team.cfg.cliffbot_site.start_xy
    seen = np.isfinite(cells) & (np.hypot(x - sx, y - sy) > 0.6)
    assert np.allclose(cells[seen], got_map[seen], atol=1e-5)
    poses = [t for m in topics["/tf"] for t in m.transforms if t.child_frame_id == "cliffbot/base_link"]
    xyz = np.array([[p.translation.x, p.translation.y, p.translation.z] for p in poses])
    assert len(poses) >= 10 and np.isfinite(xyz).all()
    names = [m.name for m in topics["/cliffbot/events"]]
    assert "cb_radio.MAP_RECEIVED" in names and "mission.STATE" in names
    assert not any(n.startswith("cb_") for n in (m.name for m in topics["/recon/events"]))
    # the Cliff-bot's link: MAVLink system 2, its modes named from the one table
    logged = load_messages(tmp_path / "cliffbot.tlog")[0]
    assert logged[-1].time_s - logged[0].time_s >= t_end - 0.5  # closed: the log holds its last second too
    beats = [lm.msg for lm in logged if lm.msg.get_type() == "HEARTBEAT"]
    assert beats and {m.get_srcSystem() for m in beats} == {2}
    modes = {mode_name(m.custom_mode) for m in beats}
    assert "WAIT_MAP" in modes and modes & {"WAIT_FIX", "DRIVE"}  # a 1 Hz heartbeat may miss a short WAIT_FIX
