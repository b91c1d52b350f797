"""Issue 29, items 1 and 4: what a lockstep mission gives the ground.

Item 1: the perception task's map updates are the preview topic (``[mavlink] map_preview_topic``),
so the mission's own .tlog carries DATA_TRANSMISSION_HANDSHAKE + ENCAPSULATED_DATA and
``safer-ground map`` renders the preview from it.
Item 4: ``--out DIR`` holds ``mission.mcap`` with Foxglove schemas: map layers, pose and mast,
camera pairs, the plan and the chosen view, events; read back with the ``mcap`` library.
Issue 5: the same seed gives the same summary (the mission run again and compared).

One lockstep mission (lab, Method 5, one imaging step, the map sent to the Cliff-bot) is shared
by the tests: a module fixture, so it runs once."""

from __future__ import annotations

import dataclasses
import json
import re
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hil_sim.mission.mission_report import strip_wall_clock
from hil_sim.mission.mission_run import RunSpec, run_mission

pytestmark = pytest.mark.timeout(900)  # one lockstep mission shared by the tests (minutes on a loaded machine)


SPEC = RunSpec("lab", "5", steps=1, seed=4, transmit=True)


@pytest.fixture(scope="module")
def mission(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    out = tmp_path_factory.mktemp("mission") / "run"
    return out, run_mission(dataclasses.replace(SPEC, out=out))


@pytest.mark.slow
def test_same_seed_same_summary(mission: tuple[Path, dict[str, Any]], tmp_path: Path) -> None:
    """Issue 5 done-when: the same seed gives an identical summary.json apart from wall-clock fields."""
    out, a = mission
    b = run_mission(dataclasses.replace(SPEC, out=tmp_path / "b"))
    assert a["final_state"] == "DONE", a["end_reason"]
    assert len(a["steps"]) == 2 and a["steps"][1]["mapped_cells"] > a["steps"][0]["mapped_cells"] > 1000
    assert (
        strip_wall_clock(a)
        == strip_wall_clock(json.loads((tmp_path / "b" / "summary.json").read_text()))
        == strip_wall_clock(b)
    )
    assert a["edge_violations"] == 0
    assert a["map_rmse_m"] is not None and a["map_rmse_m"] < 0.06  # calibrated, rectified cameras (issue 14)
    # The map reached the Cliff-bot intact within the codec's bound (docs/algorithm.md §6).
    cb = a["cliffbot"]
    assert cb is not None and cb["decoded"] and cb["max_error_m"] <= cb["bound_m"] + 1e-6
    assert (out / "map.png").stat().st_size > 0
    assert (out / "fsw.tlog").stat().st_size > 0


@pytest.mark.slow
def test_a_lockstep_mission_sends_map_previews_the_ground_renders(
        mission: tuple[Path, dict[str, Any]], tmp_path: Path) -> None:
    import cv2

    from fsw.tasks.mavlink_preview import UNKNOWN_BELOW
    from ground.cli import main as ground_main
    from ground.map_image import images_from
    from ground.tlog import load_messages

    out, summary = mission
    assert summary["steps"], summary["end_reason"]
    messages, _ = load_messages(str(out / "fsw.tlog"))
    done, _incomplete = images_from(messages)
    assert done, "no complete map preview in the mission's tlog"
    img = cv2.imdecode(np.frombuffer(done[-1].data, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert img is not None and max(img.shape) <= 128
    known = img >= UNKNOWN_BELOW
    assert 0.01 < known.mean() < 1.0  # the mapped part of the scene, and the unknown rest
    png = tmp_path / "map.png"
    assert ground_main(["map", str(out / "fsw.tlog"), "--out", str(png)]) == 0
    assert png.stat().st_size > 0


@pytest.mark.slow
def test_listen_replays_the_mission_tlog(mission: tuple[Path, dict[str, Any]],
                                        capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 29, item 5: ``safer-ground listen LOG.tlog`` shows the last screen of a run, with
    the dictionary's channel names and the mission's step."""
    from ground.cli import main as ground_main

    out, summary = mission
    capsys.readouterr()
    assert ground_main(["listen", str(out / "fsw.tlog"), "--channels", "mission.*",
                        "--steps", str(len(summary["steps"]))]) == 0
    screen = capsys.readouterr().out
    n = len(summary["steps"])
    # the mission stops its link in the frame it ends: the log's last mode may be the one before DONE
    assert re.search(r"^Mode [A-Z]+ ", screen, re.M) and re.search(rf"step [1-{n}] of {n}", screen)
    assert "mission.mapped_cells" in screen and "perception." not in screen.split("channels (red")[1].split("events")[0]


@pytest.mark.slow
def test_the_mission_mcap_holds_foxglove_channels(mission: tuple[Path, dict[str, Any]]) -> None:
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    out, summary = mission
    assert summary["files"]["recording"] == "mission.mcap"
    msgs: dict[str, list[Any]] = defaultdict(list)
    schemas: dict[str, str] = {}
    with (out / "mission.mcap").open("rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for schema, channel, _message, decoded in reader.iter_decoded_messages():
            schemas[channel.topic] = schema.name
            msgs[channel.topic].append(decoded)
    assert schemas["/recon/map/elevation"] == schemas["/recon/map/variance"] == "foxglove.Grid"
    assert schemas["/tf"] == "foxglove.FrameTransforms"
    assert schemas["/recon/camera/left"] == schemas["/recon/camera/right"] == "foxglove.CompressedImage"
    assert schemas["/recon/events"] == "foxglove.Log"
    assert schemas["/recon/plan"] == "foxglove.SceneUpdate"
    # the map grows: the last elevation grid has more known cells than the first
    grids = msgs["/recon/map/elevation"]
    known = [int(np.isfinite(np.frombuffer(g.data, "<f4")).sum()) for g in grids]
    assert len(grids) >= 2 and known[-1] > known[0] > 0 and known[-1] == summary["mapped_cells"]
    g = grids[-1]
    assert g.frame_id == "map" and len(g.data) == g.row_stride * (len(g.data) // g.row_stride)
    # the rover moves in the map frame, the mast rides on it
    tfs = [t for m in msgs["/tf"] for t in m.transforms]
    base = [t for t in tfs if t.child_frame_id == "recon/base_link"]
    assert base and {t.parent_frame_id for t in base} == {"map"}
    assert any(t.child_frame_id == "recon/mast" and t.parent_frame_id == "recon/base_link" for t in tfs)
    xs = [t.translation.x for t in base]
    assert max(xs) - min(xs) > 0.05
    # camera pairs decode as images
    import cv2
    left = msgs["/recon/camera/left"][-1]
    assert left.format == "png" and cv2.imdecode(np.frombuffer(left.data, np.uint8), cv2.IMREAD_UNCHANGED) is not None
    assert len(msgs["/recon/camera/left"]) == len(msgs["/recon/camera/right"]) >= 2
    # events as logs, named as the dictionary names them
    names = {m.name for m in msgs["/recon/events"]}
    assert any(n.startswith("mission.") for n in names)


@pytest.mark.slow
def test_a_recording_from_the_tlog_alone(mission: tuple[Path, dict[str, Any]], tmp_path: Path) -> None:
    """Issue 29, item 4: a run with only its .tlog (a real-time mission) gets a Foxglove recording
    on the ground: pose, events and the map previews the link carried; bad input is one line."""
    import cv2
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    from ground.cli import main as ground_main

    out, _ = mission
    mcap = tmp_path / "rt.mcap"
    assert ground_main(["record", str(out / "fsw.tlog"), "--out", str(mcap)]) == 0
    got: dict[str, list[Any]] = defaultdict(list)
    with mcap.open("rb") as fh:
        for schema, channel, _m, msg in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            got[channel.topic].append((schema.name, msg))
    assert got["/tf"] and {n for n, _ in got["/tf"]} == {"foxglove.FrameTransforms"}
    assert any(m.message.startswith("mission.") for _, m in got["/recon/events"])
    name, preview = got["/recon/map/preview"][-1]
    assert name == "foxglove.CompressedImage" and preview.format == "jpeg"
    assert cv2.imdecode(np.frombuffer(preview.data, np.uint8), cv2.IMREAD_GRAYSCALE) is not None
    bad = tmp_path / "bad.tlog"
    bad.write_bytes(b"nothing")
    assert ground_main(["record", str(bad), "--out", str(tmp_path / "b.mcap")]) == 2


@pytest.mark.slow
def test_a_real_time_report_from_the_checkpoint_is_the_lockstep_one(mission: tuple[Path, dict[str, Any]],
                                                                   tmp_path: Path) -> None:
    """Issue 29, item 1: ``safer-hil serve --out`` writes summary.json and the pictures from the
    flight's newest checkpoint against the truth; on a lockstep mission's checkpoints it gives the
    lockstep report's figures. No checkpoint is one line (ValueError), not a traceback."""
    import json

    from hil_sim.mission.mission_report import checkpoint_report
    from hil_sim.world import load_scenario

    out, summary = mission
    rt = checkpoint_report(tmp_path, out / "checkpoints", load_scenario("lab", SPEC.seed), scenario="lab",
                           seed=SPEC.seed, method="5", datum_m=summary["map_quality"]["datum_m"])
    assert [s["step"] for s in rt["steps"]] == [s["step"] for s in summary["steps"]]
    assert [s["mapped_cells"] for s in rt["steps"]] == [s["mapped_cells"] for s in summary["steps"]]
    assert rt["mapped_cells"] == summary["mapped_cells"] and rt["final_state"] == summary["final_state"]
    assert rt["map_rmse_m"] == pytest.approx(summary["map_rmse_m"], rel=1e-6)
    assert json.loads((tmp_path / "summary.json").read_text())["mapped_cells"] == summary["mapped_cells"]
    assert (tmp_path / "map.png").stat().st_size > 0 and (tmp_path / "coverage.png").stat().st_size > 0
    with pytest.raises(ValueError, match="no readable mission checkpoint"):
        checkpoint_report(tmp_path / "x", tmp_path / "none", load_scenario("lab", 0), scenario="lab", seed=0,
                          method="5", datum_m=0.0)
