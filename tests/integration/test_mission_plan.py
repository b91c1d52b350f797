"""Issue 29, item 2: a lockstep mission publishes its plan (stations, geofence) for the MISSION/FENCE protocol."""

from __future__ import annotations

import pytest

from hil_sim.mission.mission_run import RunSpec, mission_config


@pytest.mark.slow
def test_the_mission_publishes_its_stations_and_fence_at_each_move() -> None:
    from fsw.comm import mavlink_mission as mm
    from fsw.comm.mavlink_dialect import mavlink
    from fsw.comm.mavlink_plan import GroundPlan
    from hil_sim.bench import LockstepBench
    from hil_sim.world import load_scenario

    world = load_scenario("lab", seed=0)
    cfg = mission_config(RunSpec("lab", "5", steps=2, seed=0, transmit=False), world)
    with LockstepBench(cfg, world, seed=0, quiet=True) as b:
        box = b.exe.bus.subscribe(cfg.mavlink.plan_topic, "test", depth=64)
        mission = b.exe.tasks["mission"]
        b.run_until(lambda: len(box) >= 2 or mission.state in ("DONE", "SAFE"), 3000)
        plans = [box.get() for _ in range(len(box))]
    assert len(plans) >= 2 and all(isinstance(p, GroundPlan) for p in plans)
    last = plans[-1]
    assert len(last.stations) == len(plans) and last.current == len(last.stations) - 1
    target = (255, 190)
    items = [mm.item(last, mavlink.MAV_MISSION_TYPE_MISSION, i, target) for i in range(len(last.stations))]
    assert all(it.get_type() == "MISSION_ITEM_INT" for it in items)
    if last.fence:  # once an edge is fitted: exclusion polygons of 3 or more vertices
        assert all(len(ring) >= 3 for ring in last.fence)
