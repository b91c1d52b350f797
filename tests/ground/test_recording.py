"""Issue 29, item 4: the mission recorder's MCAP (Foxglove schemas) and its rerun conversion.

A small recording made by hand (one map, one pose, one camera pair, one event, two vehicles)
is read back with the ``mcap`` library and converted with ``safer-ground rerun``; the .rrd is
read back with rerun's own reader."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap
from fsw.framework.telemetry import Event, Severity
from ground.cli import main as ground_main
from ground.recording import MissionRecorder


@dataclass
class _Nav:
    x: float = 1.0
    y: float = 2.0
    yaw: float = 0.5
    roll: float = 0.0
    pitch: float = 0.0
    z_m: float = 0.1
    joints: tuple[float, float, float] = (0.2, -0.4, 0.3)


def _record(path: Path) -> np.ndarray:
    rec = MissionRecorder(path)
    emap = ElevationMap(MapGrid(-1.0, 0.5, 0.05, 30, 20))
    z = np.full((20, 30), np.nan)
    z[:8, 3:25] = np.linspace(0.0, 0.3, 22)[None, :]
    emap.z, emap.n = z, np.isfinite(z).astype(np.int32)
    for vehicle in ("recon", "cliffbot"):  # a second agent is a second source
        src = rec.source(vehicle)
        src.map(1.0, emap)
        src.pose(1.0, _Nav())
        src.images(1.0, np.zeros((40, 60), np.uint8), np.full((40, 60), 200, np.uint8))
        src.plan_update(1.0, [(0.0, 0.0, 0.0), (1.0, 1.0, 1.0)], [((0.0, 2.0), (1.0, 2.0), (1.0, 3.0))], 1)
        src.chosen_view(1.0, 1.0, 1.0, 1.0, "5 120 cells")
        src.event(Event(1.5, 3, "mission.STATE", Severity.WARNING_HI, "mission.STATE: MOVE"))
    rec.close()
    return z


def test_the_mcap_reads_back_with_foxglove_schemas(tmp_path: Path) -> None:
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    path = tmp_path / "m.mcap"
    z = _record(path)
    got: dict[str, list[tuple[str, object]]] = {}
    with path.open("rb") as fh:
        for schema, channel, _m, msg in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            got.setdefault(channel.topic, []).append((schema.name, msg))
    for v in ("recon", "cliffbot"):
        (name, grid), = got[f"/{v}/map/elevation"]
        assert name == "foxglove.Grid" and grid.column_count == 30 and grid.cell_size.x == pytest.approx(0.05)
        assert (grid.pose.position.x, grid.pose.position.y) == (pytest.approx(-1.0), pytest.approx(0.5))
        back = np.frombuffer(grid.data, "<f4").reshape(20, 30)  # row 0 = lowest y, as the flight map
        assert np.array_equal(np.isnan(back), np.isnan(z)) and np.allclose(back[8 - 1, 3:25], z[7, 3:25])
        (name, log), = got[f"/{v}/events"]
        assert name == "foxglove.Log" and log.name == "mission.STATE" and log.level == 4  # ERROR
        assert got[f"/{v}/camera/left"][0][0] == "foxglove.CompressedImage"
        assert {n for n, _ in got[f"/{v}/plan"] + got[f"/{v}/view"]} == {"foxglove.SceneUpdate"}
    tfs = [t for name, m in got["/tf"] for t in m.transforms]  # type: ignore[attr-defined]
    assert {t.child_frame_id for t in tfs} == {"recon/base_link", "recon/mast", "cliffbot/base_link", "cliffbot/mast"}
    base = next(t for t in tfs if t.child_frame_id == "recon/base_link")
    assert (base.translation.x, base.translation.y) == (1.0, 2.0)
    assert base.rotation.z == pytest.approx(np.sin(0.25)) and base.rotation.w == pytest.approx(np.cos(0.25))


@pytest.mark.slow
def test_safer_ground_rerun_converts_the_recording(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from rerun.chunk import RrdReader

    path = tmp_path / "m.mcap"
    _record(path)
    rrd = tmp_path / "m.rrd"
    assert ground_main(["rerun", str(path), "--out", str(rrd)]) == 0
    paths = {str(c.entity_path) for c in RrdReader(rrd).stream()}
    assert {"/recon/map/elevation", "/recon/camera/left", "/recon/events", "/cliffbot/map/elevation", "/tf"} <= paths
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap")
    capsys.readouterr()
    assert ground_main(["rerun", str(bad), "--out", str(rrd)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not an MCAP file" in err[0]
