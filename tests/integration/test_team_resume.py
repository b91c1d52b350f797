"""The whole team resumes (docs/team.md, "Running a team mission"): the team's part of a
RECON-bot checkpoint (``CliffbotAgent.state``), taken while the Cliff-bot waits for the map,
restarts the Cliff-bot from the checkpoint it held then and its hardware from where it stood;
the resumed team ends as the uninterrupted one. As in test_cliffbot_agent.py, the RECON-bot is
idle and sends the TRUE ground (no mapping): the run is the Cliff-bot's part."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from fsw.core.geometry import MapGrid
from fsw.drivers.resources import Resources
from fsw.settings import load_settings
from fsw.tasks.messages import RADIO_SEND, RadioSendRequest

pytestmark = pytest.mark.slow  # two short team runs (an idle RECON-bot, no rendering)
SEED = 3
# the map (the quarter-wheel bound) arrives about 72 frames after it is sent; the Cliff-bot's
# sixteen views (its head's scan) take about 440 more
CUT, FRAMES = 5, 600


def _run(world: Any, out: Path, resume: tuple[tuple[float, int], dict[str, Any]] | None = None,
         stop: int | None = None) -> tuple[dict[str, Any] | None, tuple[tuple[float, int], dict[str, Any]] | None]:
    """The Cliff-bot waits ``CUT`` frames, gets the map, goes on ``FRAMES`` frames (its section);
    with ``stop``: only the first ``stop`` frames, returning the bench's start and the team's
    state there (what a RECON-bot checkpoint holds); with ``resume``: from such a state."""
    from hil_sim.bench import LockstepBench
    from hil_sim.link.radio_channel import RadioChannel
    from hil_sim.team.team_bench import CliffbotAgent, FixWatch, truth_map

    cfg = load_settings()
    cfg = dataclasses.replace(cfg, map=world.map_grid, mission=dataclasses.replace(cfg.mission, auto_start=False))
    grid = MapGrid.from_config(world.map_grid)
    channel = RadioChannel(seed=SEED)
    box: list[Any] = []
    watch = FixWatch(channel, "a", lambda: box[0]() if box else 0.0)
    start = resume[0] if resume is not None else None
    with LockstepBench(cfg, world, seed=SEED, quiet=True, camera=False, resources=Resources(radio_port=watch),
                       start=start) as b:
        box.append(b.clock.now)
        team = CliffbotAgent(b, world, channel, watch, SEED, 0.0, out=out, recon_done=lambda: False,
                             resume=resume[1] if resume is not None else None)
        try:
            done = 0 if resume is None else resume[0][1]
            if stop is not None:
                b.run(stop)
                assert team.mission.state == "WAIT_MAP"
                return None, ((b.clock.now(), b.exe.frame), team.state())
            b.run(CUT - done)
            z = np.asarray(truth_map(world, grid, team.frame), np.float32)
            b.exe.ctx.bus.publish(RADIO_SEND, RadioSendRequest(1, SimpleNamespace(z=z, grid=grid)))  # type: ignore[arg-type]
            b.run(FRAMES)
            sec = team.section(None, 0.0)
            sec["estimate"] = [float(v) for v in team.mission.est.s]  # the IMU's noise stream is in it
            return sec, None
        finally:
            team.close()


def test_a_team_resumed_while_the_cliffbot_waits_ends_as_the_uninterrupted_one(tmp_path: Path) -> None:
    from hil_sim.world import load_scenario

    world = load_scenario("cliff-team", SEED)
    ref, _ = _run(world, tmp_path / "ref")
    _, saved = _run(world, tmp_path / "cut", stop=3)
    assert saved is not None and saved[1]["cliffbot"]["state"] == "WAIT_MAP"
    done, _ = _run(world, tmp_path / "cut", resume=saved)
    assert ref is not None and done is not None
    assert any(e[1] == "PLAN" for e in ref["events"])  # the resumed part holds the plan and the legs
    assert (tmp_path / "cut" / "cliffbot_checkpoints" / "cliffbot_state.json").exists()
    for key in ("events", "reached", "map_reasons", "violations", "final_state", "safe_reason", "agent",
                "link_bytes_down", "link_bytes_up", "fix_errors_cm"):
        assert done[key] == ref[key], key
    assert done["path_m"] == pytest.approx(ref["path_m"], rel=1e-9)
    assert done["estimate"] == pytest.approx(ref["estimate"], rel=1e-9, abs=1e-12)
