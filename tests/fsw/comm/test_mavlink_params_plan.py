"""Issue 29, item 2: the parameter table (ids a stock ground station can hold) and the plan for MISSION/FENCE."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
from shapely.geometry import LineString

from fsw.comm import mavlink_mission as mm
from fsw.comm import mavlink_params as mp
from fsw.comm.mavlink_dialect import mavlink
from fsw.comm.mavlink_plan import ground_plan
from fsw.core.edge.geofence import GeofenceConfig
from fsw.settings import DEFAULT_CONFIG, load_settings


def test_every_numeric_key_is_a_parameter_with_a_unique_short_id() -> None:
    cfg = load_settings(DEFAULT_CONFIG)
    table = mp.build_table(cfg)
    ids = [p.pid for p in table]
    assert len(ids) == len(set(ids)) and all(0 < len(i) <= mp.ID_LEN and not i.endswith("_") for i in ids)
    assert [p.index for p in table] == list(range(len(table)))
    keys = {p.key for p in table}
    assert "mavlink.heartbeat_period_s" in keys and "executive.frame_period_s" in keys
    assert "mavlink.url" not in keys  # strings are not parameters
    p = next(p for p in table if p.key == "mavlink.sign_downlink")
    msg = mp.param_value(p, True, len(table))
    assert msg.param_type == mavlink.MAV_PARAM_TYPE_INT32 and msg.param_value == 1.0


def test_set_values_are_refused_with_a_reason() -> None:
    f = mp.Param("MAV_HEA_PER_S", ("mavlink", "heartbeat_period_s"), float, 0)
    i = mp.Param("MAV_BUD_BYT_PER", ("mavlink", "budget_bytes_per_frame"), int, 1)
    b = mp.Param("MAV_SIG_DOW", ("mavlink", "sign_downlink"), bool, 2)
    assert mp.from_wire(f, 0.5) == 0.5 and mp.from_wire(i, 400.0) == 400 and mp.from_wire(b, 1.0) is True
    for p, v, why in ((f, math.nan, "finite"), (f, math.inf, "finite"), (i, 400.5, "integer"),
                      (b, 2.0, "0 or 1"), (i, 2.0**25, "float32")):
        with pytest.raises(ValueError, match=why):
            mp.from_wire(p, v)


def test_the_plan_serves_stations_and_the_fence_zone_in_local_ned() -> None:
    edge = SimpleNamespace(empty=False, barrier=lambda extend_m: LineString([(2.0, -1.0), (2.0, 1.0)]))
    fence = GeofenceConfig()
    plan = ground_plan([(0.0, 0.0, 0.0), (1.0, 0.5, math.pi / 2)], edge, fence)  # type: ignore[arg-type]
    assert plan.current == 1 and len(plan.fence) == 1
    ring = plan.fence[0]
    xs = [x for x, _ in ring]
    assert min(xs) == pytest.approx(2.0 - fence.margin_m, abs=0.06) and max(xs) == pytest.approx(2.0 + fence.margin_m,
                                                                                                  abs=0.06)
    target = (255, 190)
    assert mm.count(plan, mavlink.MAV_MISSION_TYPE_FENCE, target).count == len(ring)
    wp = mm.item(plan, mavlink.MAV_MISSION_TYPE_MISSION, 1, target)
    assert (wp.x, wp.y, wp.param4) == (10000, -5000, pytest.approx(-90.0))  # east = -y; yaw CW from north
    bad = mm.item(plan, mavlink.MAV_MISSION_TYPE_MISSION, 9, target)
    assert bad.get_type() == "MISSION_ACK" and bad.type == mavlink.MAV_MISSION_INVALID_SEQUENCE
    assert mm.count(plan, mavlink.MAV_MISSION_TYPE_RALLY, target).count == 0
    assert ground_plan([], None, fence).fence == ()
