"""The Cliff-bot's mission on the bench (hil_sim.team.team_run): a nominal descent and each fault
ending in a safe stop with an event (and a recovery where one exists), never a traceback.

The received map here is the true ground on the flight map grid and the RECON-bot's fixes
come from :class:`hil_sim.team.team_run.TruthFixer` (no rendering), so each run takes seconds."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from fsw.core.geometry import MapGrid
from fsw.core.team.climber_ground import ClimberConfig
from fsw.core.team.face_planner import plan_targets
from fsw.core.team.tether import TetherConfig, anchor_points
from fsw.sections import CliffbotMissionConfig
from hil_sim.faults import FaultSpec
from hil_sim.link.radio_channel import RadioChannel, RadioChannelConfig
from hil_sim.team.team_eval import truth_verdict
from hil_sim.team.team_run import TeamSetup, TruthFixer, run_team
from hil_sim.world import load_scenario

pytestmark = pytest.mark.slow
SEED = 3
GRID = MapGrid(-2.5, -9.0, 0.04, 256, 256)


@pytest.fixture(scope="module")
def scene() -> tuple[Any, np.ndarray]:
    world = load_scenario("cliff-team", SEED)
    return world, world.ground_on_grid(GRID)


def _run(scene: tuple[Any, np.ndarray], faults: tuple[FaultSpec, ...] = (), loss: float = 0.0,
         fixer: TruthFixer | None = None, **kw: Any) -> dict[str, Any]:
    world, z = scene
    setup = TeamSetup(mission=CliffbotMissionConfig(fix_timeout_s=3.0), max_s=kw.pop("max_s", 120.0))
    channel = RadioChannel(RadioChannelConfig(loss=loss), seed=SEED)
    return run_team(world, GRID, z, channel, SEED, setup, faults=faults,
                    fixer=fixer or TruthFixer(SEED), **kw)


def _events(sec: dict[str, Any], name: str) -> list[str]:
    return [e[2] for e in sec["events"] if e[1] == name]


def test_nominal_reaches_what_the_truth_allows_and_is_deterministic(scene: tuple[Any, np.ndarray]) -> None:
    a = _run(scene)
    assert a["final_state"] == "DONE", a["events"]
    assert a["targets_reached"] == a["targets_reachable_by_truth"] >= 1
    # unreachable targets are reported with a reason the truth confirms
    for k, why in enumerate(a["map_reasons"]):
        assert bool(why) == bool(a["truth_reasons"][k])
    assert a["unknown_cells_entered"] == 0 and a["reachable_missed"] == []
    assert a["tether_violations"] == 0 and a["hazard_cells_entered"] == 0
    assert a["fixes_used"] >= 1 and a["link_bytes_down"] > 0 and a["link_bytes_up"] > 0
    b = _run(scene)
    assert a == b  # same seed, same run (fault-free runs are short: the full mission twice)


def test_truth_brute_force_agrees_with_the_planner_on_the_truth(scene: tuple[Any, np.ndarray]) -> None:
    """Every lattice node judged and Dijkstra over all of them give the A* planner's verdicts
    and shortest lengths on the same (true) ground: the planner's lazy search loses nothing."""
    world, z = scene
    t, c = TetherConfig(), ClimberConfig()
    anchors = anchor_points(z, GRID, world.team.anchors_xy, t)
    truth = truth_verdict(world, GRID, anchors, t, c)
    plan = plan_targets(z, GRID, anchors, world.team.cliffbot_start_xy, world.team.targets_xyz[:, :2], t, c)
    assert truth.nodes == 128 * 128 and 0 < truth.usable < truth.nodes
    assert truth.reasons == plan.reasons and "" in truth.reasons
    np.testing.assert_allclose(truth.lengths_m, plan.lengths_m, rtol=1e-9)


@pytest.mark.parametrize("mode, bit", [("stall", "FaultStall"), ("slip", "FaultSlip"),
                                       ("overtension", "FaultOverTension")])
def test_winch_fault_safe_stop_then_recovery(scene: tuple[Any, np.ndarray], mode: str, bit: str) -> None:
    fault = FaultSpec(kind="winch_fault", start_s=4.0, duration_s=1.0, target="WINCH_A", mode=mode)
    sec = _run(scene, (fault,), recover_after_s=3.0)
    assert any(bit in e for e in _events(sec, "WINCH_FAULT")), sec["events"]
    assert any(bit in e for e in _events(sec, "SAFE"))
    assert _events(sec, "RECOVER")  # the ground command took it out of SAFE once the cause was gone
    if mode == "slip":  # the tether ran out while it slipped: the Cliff-bot slid and may now stand
        # where the planner will not drive from; then it stops again and says why
        assert sec["final_state"] == "DONE" or "start:" in sec["safe_reason"], sec["events"]
    else:
        assert sec["final_state"] == "DONE" and sec["targets_reached"] == sec["targets_reachable_by_truth"]


def test_winch_fault_without_recovery_stays_stopped(scene: tuple[Any, np.ndarray]) -> None:
    fault = FaultSpec(kind="winch_fault", start_s=4.0, target="WINCH_B", mode="stall")
    sec = _run(scene, (fault,))
    assert sec["final_state"] == "SAFE" and "WINCH_B FaultStall" in sec["safe_reason"]


def test_lost_link_ends_in_safe(scene: tuple[Any, np.ndarray]) -> None:
    sec = _run(scene, loss=1.0)
    assert sec["final_state"] == "SAFE" and sec["safe_reason"].startswith("lost link")
    assert _events(sec, "LINK_LOST") and sec["targets_reached"] == 0 and sec["path_m"] == 0.0


def test_lost_link_recovers_when_the_link_returns(scene: tuple[Any, np.ndarray]) -> None:
    world, z = scene
    setup = TeamSetup(mission=CliffbotMissionConfig(fix_timeout_s=1.5), max_s=6.0)
    channel = RadioChannel(RadioChannelConfig(outages=((0.0, 2.0),)), seed=SEED)  # no link for the first 2 s
    sec = run_team(world, GRID, z, channel, SEED, setup, fixer=TruthFixer(SEED), recover_after_s=1.0)
    names = [e[1] for e in sec["events"]]
    assert "LINK_LOST" in names and "RECOVER" in names
    assert names.index("FIX") > names.index("RECOVER") and sec["fixes_used"] >= 1  # asked again, got it
    assert sec["final_state"] != "SAFE" and sec["path_m"] > 0.0 and sec["tether_violations"] == 0


def test_a_refused_fix_recovers_on_the_fix(scene: tuple[Any, np.ndarray]) -> None:
    sec = _run(scene, fixer=TruthFixer(SEED, offset_m=(0.3, 0.0, 0.0)), recover_after_s=1.0, max_s=10.0)
    names = [e[1] for e in sec["events"]]
    assert "FIX_REFUSED" in names and "RECOVER" in names  # the ground took the fix as the estimate
    assert sec["final_state"] != "SAFE" or names.count("FIX_REFUSED") > 1, sec["events"]
    assert sec["tether_violations"] == 0 and sec["hazard_cells_entered"] == 0


def test_a_fix_that_disagrees_is_refused(scene: tuple[Any, np.ndarray]) -> None:
    sec = _run(scene, fixer=TruthFixer(SEED, offset_m=(0.6, 0.0, 0.0)))
    assert sec["final_state"] == "SAFE" and sec["safe_reason"].startswith("fix disagrees")
    assert _events(sec, "FIX_REFUSED") and sec["fixes_refused"] == 1 and sec["path_m"] == 0.0


def test_a_target_out_of_tether_reach_is_reported_not_attempted(scene: tuple[Any, np.ndarray]) -> None:
    world, _ = scene
    far = world.team.targets_xyz[:1, :2] + np.array([[0.0, -12.0]])  # off the face, far beyond the spool
    setup_world = dataclasses.replace(world)
    sec = _run((setup_world, scene[1]), command_targets=far)
    assert any("out of tether reach" in e or "off the map" in e for e in _events(sec, "TARGET_UNREACHABLE"))
    assert sec["targets_reached"] == 0 and sec["final_state"] == "DONE" and sec["path_m"] < 0.05
