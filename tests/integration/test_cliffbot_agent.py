"""The Cliff-bot as an agent (docs/team.md, "The Cliff-bot's topology"): its flight file, its
topology and tasks over the same executive, and the team mission on the lockstep bench with
both executives on one clock.

The team runs here hand the RECON-bot's radio task the TRUE ground as its map (no mapping), so
a run is the map link, the Cliff-bot's executive and its rig; the RECON-bot's mission is not
started, so its fixer answers ``busy`` and the legs go on the Cliff-bot's own estimate.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from fsw import registry
from fsw.cli import main as fsw_main
from fsw.comm.team import fix_packets
from fsw.core.geometry import MapGrid
from fsw.drivers.resources import Resources
from fsw.executive.topology import agent_topology, components
from fsw.framework.params import ConfigError
from fsw.settings import FswConfig, load_settings
from fsw.tasks.messages import RADIO_FIX_OUT, RADIO_FIX_REQUEST, RADIO_SEND, RadioSendRequest

ROOT = Path(__file__).resolve().parents[2]
CLIFFBOT_TOML = ROOT / "config" / "cliffbot.toml"
SCENE = "cliff-team"
SEED = 3


def test_the_cliffbot_file_is_its_own_topology() -> None:
    cfg = load_settings(CLIFFBOT_TOML)
    assert cfg.agent.kind == "cliffbot" and agent_topology(cfg) is registry.CLIFFBOT and cfg.mavlink.system_id == 2
    comps = components(cfg)
    kinds = {c.name: c.cls.KIND for c in comps}
    assert kinds["cb_drv"] == "cliffbot_devices" and kinds["mission"] == "cliffbot_mission"
    assert not set(kinds.values()) & set(registry.RECON_KINDS)  # none of the RECON-bot's own tasks
    # its command opcodes come from the same topology code as the RECON-bot's: component i -> (i + 1) * 0x100
    assert [c.opcode_base for c in comps] == [(i + 1) * 0x100 for i in range(len(comps))]


def test_safer_fsw_dictionary_of_the_cliffbot(capsys: pytest.CaptureFixture[str]) -> None:
    assert fsw_main(["dictionary", "--config", str(CLIFFBOT_TOML)]) == 0
    d = json.loads(capsys.readouterr().out)
    names = {c["name"] for c in d["commands"]}
    assert {"mission.RECOVER", "mission.SET_TARGETS"} <= names and "motion.DRIVE" not in names


def _without_table(text: str, name: str) -> str:
    out, skip = [], False
    for line in text.splitlines():
        if line.startswith("["):
            skip = line.split("]")[0].strip("[") == name
        if not skip:
            out.append(line)
    return "\n".join(out) + "\n"


BASE = CLIFFBOT_TOML.read_text(encoding="utf-8")


@pytest.mark.parametrize(("text", "key"), [
    (_without_table(BASE, "tether"), "tether"),  # a flight file lists every section its agent reads
    (BASE.replace("spool_m = 14.0", "spool_m = -1.0"), "tether.spool_m"),
    (BASE + "\n[stereo]\nnum_disparities_px = 64\n", "agent"),  # a section the Cliff-bot does not read
    (BASE.replace('kind = "cliffbot_radio"', 'kind = "motion"'), "executive.tasks"),  # a RECON-bot task
    (BASE.replace('kind = "cliffbot_mission"', 'kind = "noop"'), "executive.tasks"),  # no mission
    (BASE.replace("targets_xy = [4.49, -1.49, 2.1, -1.25]", "targets_xy = [4.49]"), "cliffbot_site"),
    (BASE.replace("anchor_a_xyz = [1.0, 0.6, 0.0]", "anchor_a_xyz = [1.0, nan, 0.0]"), "cliffbot_site.anchor_a_xyz[1]"),
])
def test_a_cliffbot_file_that_does_not_fit_is_refused(tmp_path: Path, text: str, key: str) -> None:
    p = tmp_path / "cb.toml"
    p.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as err:
        load_settings(p)
    assert err.value.key == key and "\n" not in str(err.value)


def test_the_recon_file_needs_no_cliffbot_section() -> None:
    cfg = load_settings()
    assert cfg.agent.kind == "recon" and "tether" not in registry.RECON.sections


# -- the team on the lockstep bench ---------------------------------------------------------------

@pytest.fixture(scope="module")
def world() -> Any:
    from hil_sim.world import load_scenario

    return load_scenario(SCENE, SEED)


def _recon_cfg(world: Any) -> FswConfig:
    """The RECON-bot idle, its map link reduced for the Cliff-bot as the flight file says, its map
    sync on as in a team mission (docs/sync.md, "In flight")."""
    cfg = load_settings()
    return dataclasses.replace(cfg, map=world.map_grid, mission=dataclasses.replace(cfg.mission, auto_start=False),
                               map_sync=dataclasses.replace(cfg.map_sync, enabled=True))


def _team(world: Any, frames: int, faults: tuple[Any, ...] = (), out: Path | None = None,
          ) -> tuple[dict[str, Any], list[tuple[float, str, str]]]:
    """The Cliff-bot's mission beside an idle RECON-bot that sends the true ground as its map."""
    from hil_sim.bench import LockstepBench
    from hil_sim.link.radio_channel import RadioChannel
    from hil_sim.team.team_bench import CliffbotAgent, FixWatch, truth_map

    grid = MapGrid.from_config(world.map_grid)
    channel = RadioChannel(seed=SEED)
    box: list[Any] = []
    watch = FixWatch(channel, "a", lambda: box[0]() if box else 0.0)
    with LockstepBench(_recon_cfg(world), world, seed=SEED, quiet=True, camera=False,
                       resources=Resources(radio_port=watch)) as b:
        box.append(b.clock.now)
        team = CliffbotAgent(b, world, channel, watch, SEED, 0.0, out=out, faults=faults, recon_done=lambda: False)
        try:
            b.run(3)  # the Cliff-bot waits for the map from t = 0
            assert team.mission.state == "WAIT_MAP" and team.exe.frame == 3
            z = np.asarray(truth_map(world, grid, team.frame), np.float32)
            b.exe.ctx.bus.publish(RADIO_SEND, RadioSendRequest(1, SimpleNamespace(z=z, grid=grid)))  # type: ignore[arg-type]
            for _ in range(frames):
                b.run(1)
                if team.finished():
                    break
            sec = team.section(out, 0.0)
            # the Cliff-bot's own cells standing 0.2 m over the true ground where it is not steep (its
            # body is 0.56 m high, a tether 0.15-0.3 m over the ground; its stereo's worst error on
            # such ground at 2.5 m is about 0.17 m); steep cells are the face map's business (issue 28)
            own = next(t for t in team.exe.tasks.values() if t.KIND == "cliffbot_sensing").own_map()  # type: ignore[attr-defined]
            gy, gx = np.gradient(np.asarray(z, float), grid.cell)
            flat = np.degrees(np.arctan(np.hypot(gx, gy))) < 20.0
            with np.errstate(invalid="ignore"):
                sec["own_cells_above_truth"] = int(np.sum((own - z > 0.2) & flat))
                sec["own_flat_cells"] = int(np.sum(np.isfinite(own) & flat))
            trace = [(e.time_s, e.name, e.text) for e in team.exe.events.history]  # timing on the stepped clock
        finally:
            team.close()
    return sec, trace


@pytest.fixture(scope="module")
def mission(world: Any, tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, Any], list[Any], Path]:
    out = tmp_path_factory.mktemp("team")
    sec, trace = _team(world, 2500, out=out)
    return sec, trace, out


@pytest.mark.slow
@pytest.mark.timeout(900)  # a team mission with the Cliff-bot's own views: minutes on a loaded machine
def test_the_team_mission_runs_two_executives_on_one_clock(mission: tuple[dict[str, Any], list[Any], Path]) -> None:
    a, trace, out = mission
    assert a["map_received"] and a["agent"] == {"name": "cliffbot-1", "kind": "cliffbot", "mavlink_system_id": 2,
                                                "frames": a["agent"]["frames"]}
    assert a["final_state"] == "DONE", a["events"]
    assert a["targets_reached"] >= 1 and a["tether_violations"] == sum(a["violations"].values())
    assert a["hazard_cells_entered"] == 0 and a["unknown_cells_entered"] == 0
    for k, why in enumerate(a["map_reasons"]):  # what it did not reach, it says why
        assert bool(why) != a["reached"][k]
    assert a["link_bytes_down"] > 1000 and a["link_bytes_up"] > 0  # the map down, acks and fix requests up
    assert any(n == "cb_radio.MAP_RECEIVED" for _, n, _ in trace)
    assert any(n == "mission.FIX_UNAVAILABLE" and "busy" in t for _, n, t in trace)  # the RECON-bot is not done
    assert (out / "team.png").stat().st_size > 0
    # the team figures (hil_sim.team.team_figures): the idle RECON-bot takes no imaging step here;
    # the Cliff-bot looked round before its plan (docs/team.md, "Both agents sense")
    assert a["cells_by_agent"]["cliffbot"] > 300 and a["sync_source"] == "flown"
    # the map sync: the RECON-bot's round of the map it sent, the Cliff-bot's one per look
    assert [e["rounds"] for e in a["sync_ends"]] == [1, len(a["views"])] and a["sync_ends"][1]["tiles_published"] > 0
    assert [v["agent"] for c in a["views"] for v in c["views"]] == ["cliffbot"] * len(a["views"])
    assert a["sync_full_resends"] == 0 and a["face_rmse_m"] is None and a["face_note"]
    merged = [t for _, n, t in trace if n == "cb_sense.VIEW_MERGED"]
    assert len(merged) >= 8 and any(n == "mission.SENSED" for _, n, _ in trace)
    # its body and the tethers are masked out of its views (judged on the truth: the received map here)
    assert a["own_flat_cells"] > 300 and a["own_cells_above_truth"] == 0


@pytest.mark.slow
@pytest.mark.timeout(900)  # a team mission with the Cliff-bot's own views: minutes on a loaded machine
def test_the_cliffbot_checkpoints_and_continues_from_one(mission: tuple[dict[str, Any], list[Any], Path],
                                                          world: Any) -> None:
    """The last checkpoint (mission DONE) holds the map and the estimate; a Cliff-bot started on
    it continues from there (RESUMED) instead of waiting for a map."""
    from fsw.app import build_executive
    from fsw.framework.clock import SteppedClock
    from fsw.tasks.cliffbot.checkpoint import CheckpointFile

    a, _, out = mission
    got = CheckpointFile(str(out / "cliffbot_checkpoints")).load()
    assert got is not None and got[0]["state"] == "DONE" and got[1] is not None
    cfg = load_settings(CLIFFBOT_TOML)
    cfg = dataclasses.replace(
        cfg, map=world.map_grid,
        checkpoint=dataclasses.replace(cfg.checkpoint, directory=str(out / "cliffbot_checkpoints")),
        cliffbot_bus=dataclasses.replace(cfg.cliffbot_bus, can_interface="none"))
    from fsw.drivers.radio import open_radio

    radio = open_radio("inproc://cliffbot-resume-test")
    exe = build_executive(cfg, SteppedClock(), Resources(radio_port=radio), map_store=False)
    try:
        m = exe.tasks["mission"].mission  # type: ignore[attr-defined]
        assert m.state == "DONE" and m.z is not None and list(m.reached) == a["reached"]
        assert any(e.name == "mission.RESUMED" for e in exe.events.history)
        exe.tasks["mavlink"].close()  # type: ignore[attr-defined]
    finally:
        radio.close()


@pytest.mark.slow
@pytest.mark.timeout(900)  # a team mission with the Cliff-bot's own views: minutes on a loaded machine
def test_the_team_is_deterministic(world: Any) -> None:
    # the map (about 8 kB at 9600 bit/s), the Cliff-bot's own views (rendered, fused in slack jobs),
    # the plan, a fix request and the first moves
    a = _team(world, 650)
    b = _team(world, 650)
    assert any(n == "cb_sense.SENSED" for _, n, _ in a[1]) and a[0]["cells_by_agent"]["cliffbot"] > 0
    assert a[0]["events"] and a == b


@pytest.mark.slow
def test_a_winch_stall_is_a_safe_stop_through_the_executive(world: Any) -> None:
    from hil_sim.faults import FaultSpec

    stall = FaultSpec(kind="winch_fault", start_s=12.0, target="WINCH_B", mode="stall")
    sec, trace = _team(world, 600, faults=(stall,))
    assert sec["final_state"] == "SAFE" and "WINCH_B FaultStall" in sec["safe_reason"]
    assert any(n == "mission.SAFE" for _, n, _ in trace) and any(n == "mission.WINCH_FAULT" for _, n, _ in trace)


def test_the_recon_fixer_answers_busy_while_its_mission_runs() -> None:
    """The RECON-bot's fixer (flight code): a request before its mission has ended is told
    ``busy`` through the radio's fix topic, ahead of any map bytes."""
    from hil_sim.bench import LockstepBench

    cfg = load_settings()
    cfg = dataclasses.replace(cfg, mission=dataclasses.replace(cfg.mission, auto_start=False))
    with LockstepBench(cfg, None, seed=0, quiet=True, camera=False) as b:
        out = b.exe.ctx.bus.subscribe(RADIO_FIX_OUT, "test", depth=4)
        b.run(2)
        b.exe.ctx.bus.publish(RADIO_FIX_REQUEST, fix_packets.FixRequest(7, 0, 1.0, -2.0))
        b.run(2)
        got = [fix_packets.decode(p) for p in out.drain()]
    assert got == [fix_packets.NoFix(7, 2)]


def test_a_fix_request_carries_the_estimate() -> None:
    req = fix_packets.FixRequest(3, 1, 2.5, -0.75)
    assert fix_packets.decode(fix_packets.encode(req)) == req
    old = fix_packets.decode(fix_packets.encode(fix_packets.FixRequest(3, 1)))
    assert old.seq == 3 and math.isnan(old.x)  # type: ignore[union-attr]


@pytest.mark.slow
@pytest.mark.timeout(600)  # real time beside a loaded machine: the waits below end a hang
def test_real_time_the_cliffbot_flies_on_the_serve_benchs_team_bus(tmp_path: Path) -> None:
    """``safer-hil serve --scenario cliff-team`` plays the Cliff-bot's hardware on a team CAN hub and
    writes its flight file; ``safer-fsw run --config`` that file connects with unchanged code: the
    winches hear its commands (none refused) and it waits for the map without a SAFE stop."""
    import os
    import signal
    import subprocess
    import sys

    from hil_helpers import read_until

    bin_dir = Path(sys.executable).parent
    recon, cb = tmp_path / "recon.toml", tmp_path / "cliffbot.toml"
    serve = subprocess.Popen(
        [str(bin_dir / "safer-hil"), "serve", "--scenario", "cliff-team", "--seed", "3", "--can-port", "0",
         "--flight-config", str(recon), "--cliffbot-config", str(cb), "--duration", "300", "--report-period", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        read_until(serve, "READY", 180.0)  # after the flight files; returns at READY, the limit only ends a hang
        assert cb.exists(), "serve wrote no Cliff-bot flight file"
        assert load_settings(cb).cliffbot_bus.can_interface == "udp_hub"
        assert load_settings(recon).link.peer == load_settings(cb).link.transport  # one radio, two ends
        run = subprocess.run([str(bin_dir / "safer-fsw"), "run", "--config", str(cb), "--duration", "3"],
                             capture_output=True, text=True, timeout=90)
        assert run.returncode == 0, run.stderr
        assert "agent cliffbot-1 (cliffbot, MAVLink system 2)" in run.stdout
        assert "SAFE" not in run.stdout and "NO_BUS" not in run.stdout, run.stdout
    finally:
        serve.send_signal(signal.SIGINT)
        out, _ = serve.communicate(timeout=30)
    truth = json.loads(next(ln for ln in out.splitlines() if ln.startswith("TRUTH "))[6:])
    assert truth["winch_commands"] > 20 and truth["winch_bad"] == 0


@pytest.mark.parametrize("state", ['{"schema": 1, "state": "DRIVE"', '[1, 2]',
                                   '{"schema": 1, "state": "FLY", "targets": [], "nav_s": [0, 0, 0]}'])
def test_a_bad_checkpoint_is_refused_in_one_line(tmp_path: Path, state: str) -> None:
    """A Cliff-bot started on a checkpoint it cannot use says so (one line) and waits for a map."""
    from fsw.app import build_executive
    from fsw.drivers.radio import open_radio
    from fsw.framework.clock import SteppedClock

    (tmp_path / "cliffbot_state.json").write_text(state, encoding="utf-8")
    cfg = load_settings(CLIFFBOT_TOML)
    cfg = dataclasses.replace(cfg, checkpoint=dataclasses.replace(cfg.checkpoint, directory=str(tmp_path)),
                              cliffbot_bus=dataclasses.replace(cfg.cliffbot_bus, can_interface="none"))
    radio = open_radio("inproc://cliffbot-bad-checkpoint")
    try:
        exe = build_executive(cfg, SteppedClock(), Resources(radio_port=radio), map_store=False)
        refused = [e.text for e in exe.events.history if e.name == "mission.CHECKPOINT_REFUSED"]
        assert len(refused) == 1 and "\n" not in refused[0]
        assert exe.tasks["mission"].mission.state == "WAIT_MAP"  # type: ignore[attr-defined]
        exe.tasks["mavlink"].close()  # type: ignore[attr-defined]
    finally:
        radio.close()


def test_navigation_is_its_own_task_and_takes_the_checkpoints_estimate(tmp_path: Path) -> None:
    """The EKF runs in ``cb_nav`` (scheduled before the mission); a Cliff-bot restarted on a
    checkpoint goes on from its estimate in both tasks (never the start's in between)."""
    from fsw.app import build_executive
    from fsw.drivers.radio import open_radio
    from fsw.framework.clock import SteppedClock
    from fsw.tasks.cliffbot.checkpoint import SCHEMA, CheckpointFile

    s = [2.6, -0.7, -1.2]
    p = np.diag([0.03**2, 0.04**2, 0.02**2])
    CheckpointFile(str(tmp_path)).save({
        "schema": SCHEMA, "time_s": 5.0, "state": "WAIT_MAP", "safe_reason": "", "leg_i": 0, "fix_seq": 0,
        "map_version": 0, "start": [2.5, -0.5], "targets": [[2.0, -1.5]], "reached": [False], "reasons": [""],
        "legs": [], "nav_s": s, "nav_P": p.tolist()}, None)
    cfg = load_settings(CLIFFBOT_TOML)
    cfg = dataclasses.replace(cfg, checkpoint=dataclasses.replace(cfg.checkpoint, directory=str(tmp_path)),
                              cliffbot_bus=dataclasses.replace(cfg.cliffbot_bus, can_interface="none"))
    radio = open_radio("inproc://cliffbot-nav-task")
    try:
        exe = build_executive(cfg, SteppedClock(), Resources(radio_port=radio), map_store=False)
        order = [t.name for t in exe.tasks.values()]
        assert exe.tasks["cb_nav"].KIND == "cliffbot_nav" and order.index("cb_nav") < order.index("mission")
        m = exe.tasks["mission"].mission  # type: ignore[attr-defined]
        seen = []
        for _ in range(4):
            exe.step()
            seen.append(m.est.s.copy())
        nav = exe.tasks["cb_nav"].nav.nav  # type: ignore[attr-defined]
        np.testing.assert_allclose(nav.s, s, atol=1e-9)  # the checkpoint's estimate, not the start
        for e in seen:  # never the navigation's start estimate in between
            np.testing.assert_allclose(e, s, atol=1e-9)
        assert any(e.name == "cb_nav.NAV_RESET" for e in exe.events.history)
        exe.tasks["mavlink"].close()  # type: ignore[attr-defined]
    finally:
        radio.close()


def test_a_cliffbot_restarted_on_a_checkpoint_senses_on_its_map(tmp_path: Path) -> None:
    """No map comes over the link after a restart: the sensing task takes the checkpoint's map
    (the mission's, less the plane carried on beyond where its wheels stood) as the received
    one, so a request for views is answered on it (the mission never waits out its timeout)."""
    from fsw.app import build_executive
    from fsw.drivers.radio import open_radio
    from fsw.framework.clock import SteppedClock
    from fsw.tasks.cliffbot.checkpoint import SCHEMA, CheckpointFile

    cfg = load_settings(CLIFFBOT_TOML)
    z = np.zeros((cfg.map.ny, cfg.map.nx))
    z[:10] = np.nan
    carried = [cfg.map.nx * 20 + 5, cfg.map.nx * 21 + 7]
    CheckpointFile(str(tmp_path)).save({
        "schema": SCHEMA, "time_s": 5.0, "state": "WAIT_FIX", "safe_reason": "", "leg_i": 0, "fix_seq": 1,
        "map_version": 2, "error_bound_m": 0.03, "start": [2.5, -0.5], "targets": [[2.0, -1.5]],
        "reached": [False], "reasons": ["unknown ground"], "legs": [[2.0, -1.5, 0]], "nav_s": [2.5, -0.5, -1.57],
        "nav_P": np.diag([1e-4, 1e-4, 1e-4]).tolist(), "carried": carried}, z)
    cfg = dataclasses.replace(cfg, checkpoint=dataclasses.replace(cfg.checkpoint, directory=str(tmp_path)),
                              cliffbot_bus=dataclasses.replace(cfg.cliffbot_bus, can_interface="none"))
    radio = open_radio("inproc://cliffbot-sense-resume")
    try:
        exe = build_executive(cfg, SteppedClock(), Resources(radio_port=radio), map_store=False)
        for _ in range(4):
            exe.step()
        got = exe.tasks["cb_sense"].received  # type: ignore[attr-defined]
        assert got is not None and got.error_bound_m == pytest.approx(0.03)
        held = np.isfinite(got.z)
        assert not held[:10].any() and not held.flat[carried].any()  # unknown, and the plane carried on
        assert held.sum() == z.size - 10 * cfg.map.nx - len(carried)
        exe.tasks["mavlink"].close()  # type: ignore[attr-defined]
    finally:
        radio.close()
