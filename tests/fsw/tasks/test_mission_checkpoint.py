"""Issue 12, item 1: the step checkpoint (map + mission state in one file) and the flight
software's resume at start-up (what `safer-fsw run` does), without the bench."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zstandard
from hypothesis import given, settings
from hypothesis import strategies as st

from fsw.app import build_executive
from fsw.core.geometry import MapGrid
from fsw.core.map.checkpoint import MAGIC, CheckpointError, decode, encode
from fsw.core.map.elevation_map import ElevationMap
from fsw.drivers.map_store import MapStore
from fsw.drivers.resources import Resources
from fsw.framework.clock import SteppedClock
from fsw.settings import load_settings
from fsw.tasks.messages import NavPose
from fsw.tasks.mission_state import (
    MissionPhase,
    StateError,
    edge_from_json,
    edge_to_json,
    fingerprint,
    mask_from_json,
    mask_to_json,
    nav_to_json,
)

pytestmark = pytest.mark.req("12.1")


def small_cfg(tmp_path: Path) -> Any:
    cfg = load_settings()
    grid = dataclasses.replace(cfg.map, nx=64, ny=48)
    ckpt = dataclasses.replace(cfg.checkpoint, directory=str(tmp_path / "ckpt"))
    return dataclasses.replace(cfg, map=grid, checkpoint=ckpt)


def some_map(cfg: Any, seed: int = 0) -> ElevationMap:
    rng = np.random.default_rng(seed)
    m = ElevationMap(MapGrid.from_config(cfg.map), cfg.fusion)
    g = m.grid
    pts = np.column_stack([rng.uniform(g.x0, g.x0 + g.nx * g.cell, 2000),
                           rng.uniform(g.y0, g.y0 + g.ny * g.cell, 2000), rng.normal(0, 0.1, 2000)])
    m.merge(pts, var_z=np.full(2000, 1e-4), p_visible=np.full(g.shape, 0.7))
    return m


def step_state(cfg: Any, step: int = 3, phase: str = "SELECT", **over: Any) -> dict[str, Any]:
    nav = NavPose(10.0, 0.4, -1.2, 0.3, np.diag([1e-4, 2e-4, 3e-5]), (0.1, -0.5, 0.4))
    mission = {
        "phase": phase, "step": step, "request_id": 7, "edge_violations": 0, "safe_entries": 0,
        "end": None, "safe_reason": None, "edge": None, "nav": nav_to_json(nav),
        "records": [{"step": k, "mapped_cells": 100 * (k + 1), "expected_new_cells": 50.0, "obtained_new_cells": 100,
                     "pose": {"x": 0.0, "y": 0.0, "yaw": 0.0, "pan": 0.0, "tilt": 0.0, "lift": 0.5},
                     "wall_s": 1.0, "sim_s": 5.0 * k} for k in range(step)],
        "latest": {"view_id": step - 1, "time_s": 9.0, "mapped_cells": 1234, "new_cells": 10, "points": 99,
                   "misses": 0, "expected_new_cells": 50.0, "edge": None, "extra": {"roi_mapped_fraction": 0.4}},
    }
    motion = {"pose": [0.4, -1.2, 0.3], "path_m": 2.5, "turned_rad": 1.0, "yaw_acc": 0.3, "done": 4, "aborted": 0,
              "last_drive": None, "steer_hold": [0.0] * 4, "setpoints": None}
    state = {"schema": 1, "fingerprint": fingerprint(cfg), "time_s": 12.0, "frame": 120,
             "mission": mission, "tasks": {"motion": motion, "perception": {"views": step + 2}}, "hooks": {}}
    state.update(over)
    return state


_open: list[Any] = []


@pytest.fixture(autouse=True)
def _close_executives() -> Any:
    yield
    from fsw.drivers.factory import close_devices

    while _open:
        res = _open.pop().ctx.res
        close_devices(res)
        assert res.radio_port is not None
        res.radio_port.close()


def boot(cfg: Any, store: MapStore) -> Any:
    """The flight software's start-up on a stepped clock (what `safer-fsw run` builds)."""
    from fsw.drivers.radio import open_radio

    radio = open_radio(f"inproc://resume-test-{len(_open)}-{id(store)}")
    exe = build_executive(cfg, SteppedClock(12.0), Resources(map_store=store, radio_port=radio))
    _open.append(exe)
    return exe


def events(exe: Any, name: str) -> list[Any]:
    return [e for e in exe.events.history if e.name.endswith(name)]


def test_state_round_trips_with_the_map(tmp_path: Path) -> None:
    cfg = small_cfg(tmp_path)
    m, state = some_map(cfg), step_state(cfg)
    back, meta = decode(encode(m, 5, 12.0, state=state))
    assert meta.state == state and meta.seq == 5
    np.testing.assert_array_equal(back.z, m.z)


def test_version_1_map_only_files_still_load(tmp_path: Path) -> None:
    """A checkpoint written by the previous build (version 1, map only) loads, without state."""
    cfg = small_cfg(tmp_path)
    m = some_map(cfg)
    blob = encode(m, 2, 1.0)
    hlen = struct.unpack_from("<8sHI", blob)[2]
    header = json.loads(blob[14:14 + hlen])
    del header["state_len"], header["state_raw_len"]
    h = json.dumps(header).encode()
    v1 = struct.pack("<8sHI", MAGIC, 1, len(h)) + h + blob[14 + hlen:-32]
    v1 += hashlib.sha256(v1).digest()
    back, meta = decode(v1)
    assert meta.state is None and meta.version == 1
    np.testing.assert_array_equal(back.n, m.n)


@settings(max_examples=30, deadline=None)
@given(st.data())
def test_any_damage_to_a_checkpoint_with_state_is_detected(data: Any) -> None:
    cfg = load_settings()
    cfg = dataclasses.replace(cfg, map=dataclasses.replace(cfg.map, nx=16, ny=12))
    blob = encode(ElevationMap(MapGrid.from_config(cfg.map), cfg.fusion), 1, 0.0, state=step_state(cfg))
    pos = data.draw(st.integers(0, len(blob) - 1))
    bad = bytearray(blob)
    bad[pos] ^= 1 << data.draw(st.integers(0, 7))
    with pytest.raises(CheckpointError):
        decode(bytes(bad))
    with pytest.raises(CheckpointError):
        decode(blob[:data.draw(st.integers(0, len(blob) - 1))])


def test_state_that_is_not_an_object_is_refused() -> None:
    """A checksummed file whose state section is valid JSON but not an object: refused."""
    cfg = load_settings()
    blob = encode(ElevationMap(MapGrid(0, 0, 0.1, 4, 4)), 1, 0.0, state={"x": 1})
    hlen = struct.unpack_from("<8sHI", blob)[2]
    header = json.loads(blob[14:14 + hlen])
    body = blob[14 + hlen:14 + hlen + header["body_len"]]
    sz = zstandard.ZstdCompressor().compress(b"[1, 2]")
    header.update(state_len=len(sz), state_raw_len=6)
    h = json.dumps(header).encode()
    out = struct.pack("<8sHI", MAGIC, 2, len(h)) + h + body + sz
    with pytest.raises(CheckpointError, match="not an object"):
        decode(out + hashlib.sha256(out).digest(), cfg.fusion)


def test_stale_temporaries_removed_and_sequence_continues(tmp_path: Path) -> None:
    cfg = small_cfg(tmp_path)
    store = MapStore(cfg.checkpoint, cfg.fusion)
    store.save_next(some_map(cfg), 1.0)
    store.save_next(some_map(cfg), 2.0)
    for i in range(3):  # what kills during save leave behind
        (store.dir / f".map_{i}abc.tmp").write_bytes(b"half")
    fresh = MapStore(cfg.checkpoint, cfg.fusion)
    res = fresh.restore()
    assert res.stale_removed == 3 and not list(store.dir.glob("*.tmp"))
    assert res.meta is not None and res.meta.seq == 2 and res.state is None
    assert fresh.save_next(some_map(cfg), 3.0).name == "map_0000000003.ckpt"


def test_flight_software_resumes_at_the_next_step(tmp_path: Path) -> None:
    """`safer-fsw run` start-up: map, step, records, odometry and counters come back; the
    mission is in SELECT for step 3 and has asked for the next view (not INIT, no panorama)."""
    cfg = small_cfg(tmp_path)
    store = MapStore(cfg.checkpoint, cfg.fusion)
    m = some_map(cfg)
    store.save_next(m, 12.0, step_state(cfg))
    (store.dir / ".map_x.tmp").write_bytes(b"")
    exe = boot(cfg, MapStore(cfg.checkpoint, cfg.fusion))
    mission, motion, perception = (exe.tasks[k] for k in ("mission", "motion", "perception"))
    assert mission.state == MissionPhase.SELECT and mission.step == 3 and len(mission.records) == 3
    assert events(exe, "RESUMED") and events(exe, "STALE_REMOVED")
    assert motion.odo.pose == (0.4, -1.2, 0.3) and motion.odo.path_m == 2.5 and perception.views == 5
    np.testing.assert_array_equal(perception.map.z, m.z)
    assert mission.nav is not None and mission.nav.cov[1, 1] == 2e-4
    exe.step()
    assert exe.telemetry.get("mission.state") == "SELECT"


@pytest.mark.parametrize("phase", ["DONE", "SAFE"])
def test_done_and_safe_missions_stay_so(tmp_path: Path, phase: str) -> None:
    """A finished mission is not flown again; a SAFE one still waits for RESUME."""
    cfg = small_cfg(tmp_path)
    MapStore(cfg.checkpoint, cfg.fusion).save_next(some_map(cfg), 12.0, step_state(cfg, phase=phase))
    exe = boot(cfg, MapStore(cfg.checkpoint, cfg.fusion))
    for _ in range(3):
        exe.step()
    assert exe.tasks["mission"].state == phase


@pytest.mark.parametrize("damage", ["fingerprint", "schema", "phase", "records", "tasks", "edge"])
def test_incompatible_or_malformed_state_is_an_event_not_a_crash(tmp_path: Path, damage: str) -> None:
    """Refused with RESUME_REFUSED; the mission waits for START instead of starting over."""
    cfg = small_cfg(tmp_path)
    state = step_state(cfg)
    if damage == "fingerprint":
        state = step_state(dataclasses.replace(cfg, mission=dataclasses.replace(cfg.mission, method="2")))
    elif damage == "schema":
        state["schema"] = 99
    elif damage == "phase":
        state["mission"]["phase"] = "MOVE"
    elif damage == "edge":
        state["mission"]["edge"] = {"method": "polygon", "points_xy": [], "lines": "00ff", "safe_polygon": None}
    elif damage == "records":
        state["mission"]["records"] = [{"step": "x"}]
    else:
        state["tasks"]["motion"] = {"pose": "nonsense"}
    MapStore(cfg.checkpoint, cfg.fusion).save_next(some_map(cfg), 12.0, state)
    exe = boot(cfg, MapStore(cfg.checkpoint, cfg.fusion))
    exe.step()
    refused = events(exe, "RESUME_REFUSED")
    assert exe.tasks["mission"].state == MissionPhase.IDLE and len(refused) == 1
    if damage == "tasks":
        assert "motion" in refused[0].text


def test_edge_model_round_trip() -> None:
    from shapely.geometry import MultiLineString, Polygon

    from fsw.core.edge.edge import EdgeModel

    e = EdgeModel("polygon", np.array([[0.1, 0.2], [0.3, 0.4]]), MultiLineString([[(0, 0), (1, 0.5)]]),
                  Polygon([(0, 0), (1, 0), (1, 1)]))
    back = edge_from_json(json.loads(json.dumps(edge_to_json(e))))
    assert back is not None and back.lines.equals_exact(e.lines, 0) and back.safe_polygon is not None
    assert back.safe_polygon.equals_exact(e.safe_polygon, 0)
    np.testing.assert_array_equal(back.points_xy, e.points_xy)


def test_the_drop_mask_survives_a_checkpoint_and_a_corrupt_one_is_refused() -> None:
    """The drop cells the geofence uses while no edge is fitted (``MapUpdate.drop``) are part
    of the mission state: a resumed mission judges its moves as the uninterrupted one."""
    rng = np.random.default_rng(3)
    mask = rng.random((37, 53)) < 0.2
    back = mask_from_json(mask_to_json(mask), (37, 53))
    assert back is not None and back.dtype == bool and (back == mask).all()
    assert mask_from_json(None, (37, 53)) is None
    with pytest.raises(StateError, match="shape"):
        mask_from_json(mask_to_json(mask), (53, 37))
    bad = mask_to_json(mask)
    assert bad is not None
    for bits in ("!!!not base64", bad["bits"][:-8]):
        with pytest.raises(StateError):
            mask_from_json({"shape": [37, 53], "bits": bits}, (37, 53))


def test_a_checkpoint_holds_no_wall_clock_time() -> None:
    """A lockstep run's checkpoints are the same bytes every time (docs/architecture.md, "The
    cyclic executive"): two runs whose steps took the host different times write the same
    mission section, and a step read back has no wall time (the summary says null)."""
    from fsw.tasks.mission_state import StepRecord, records_from_json, records_to_json

    def record(wall_s: float) -> StepRecord:
        return StepRecord(2, 1500, 80.0, 95, {"x": 0.1, "y": -0.2, "yaw": 0.3, "pan": 0.0, "tilt": -0.4, "lift": 0.5},
                          wall_s, 41.5, "5", 60)

    fast, slow = json.dumps(records_to_json([record(3.2)])), json.dumps(records_to_json([record(187.25)]))
    assert fast == slow and "wall_s" not in fast
    (back,) = records_from_json(json.loads(fast))
    assert back == dataclasses.replace(record(0.0), wall_s=None)
