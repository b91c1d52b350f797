"""The team-views harness and the team figures it puts in a summary's ``team`` section
(hil_sim.team.team_views_run, hil_sim.team.team_figures; ``safer-hil experiment team-sensing``)."""

from __future__ import annotations

import json
import math

import pytest

from fsw.core.planning.team_views import TeamViewConfig
from hil_sim.team.team_views_run import run_scene

KEYS = ("cells_by_agent", "sync_hash_equal", "sync_rounds", "sync_bytes", "sync_minimal_bytes",
        "sync_full_resends", "face_rmse_m", "face_rmse_gravity_m", "views")


@pytest.mark.slow
def test_three_team_cycles_fill_every_team_key_with_real_numbers() -> None:
    run = run_scene("cliff-team", 3, team=True, cycles=3)  # a scene whose face is fitted in its first cycle
    sec = json.loads(json.dumps(run.section()))  # what summary.json would hold
    assert all(k in sec for k in KEYS)
    assert sec["cells_by_agent"]["recon"] > 100 and sec["cells_by_agent"]["cliffbot"] > 100
    assert sec["sync_hash_equal"] is True and sec["sync_rounds"] == 3 and sec["sync_full_resends"] == 0
    # the tiles of a round share TILEs, so the bytes delivered may be below the minimal deltas
    # (one tile a packet), never above what was put on the air
    assert 0 < sec["sync_bytes"] <= min(1.2 * sec["sync_minimal_bytes"], sec["sync_air_bytes"])
    for k in ("face_rmse_m", "face_rmse_gravity_m"):
        assert isinstance(sec[k], float) and 0.0 < sec[k] < 1.0, sec.get("face_note")
    assert [c["cycle"] for c in sec["views"]] == [1, 2, 3]
    for c in sec["views"]:
        agents = [v["agent"] for v in c["views"]]
        # the RECON-bot's view and the Cliff-bot's head scan, from one place
        assert agents.count("recon") == 1 and 1 <= agents.count("cliffbot") <= TeamViewConfig().cliffbot_views
        assert len({tuple(v["xyz"]) for v in c["views"] if v["agent"] == "cliffbot"}) == 1
        assert 0.0 <= c["overlap"] <= 1.0
        for v in c["views"]:
            assert v["obtained_new_cells"] <= v["obtained_cells"] and math.isfinite(v["expected_new_cells"])
            assert v["added_cells"] >= 0  # what it made known on the map (its points may fall beside its cells)
            assert v["why"].startswith(v["agent"])
    added = sum(v["added_cells"] for c in sec["views"] for v in c["views"])
    assert added == sum(r.new_cells for r in run.records) > 0  # the views' own shares make up each cycle's
    # what bounds the corridor: its unmapped cells, some of them seeable from the next candidates
    left = run.corridor_left()
    import numpy as np

    unmapped = run.corridor & ~run.map.mapped & np.isfinite(run.truth)
    assert left["corridor_left_cells"] == int(unmapped.sum()) > 0
    assert 0 < left["corridor_left_seeable"] <= left["corridor_left_cells"]
    # the same seed gives the same cycles
    again = run_scene("cliff-team", 3, team=True, cycles=1)
    assert json.loads(json.dumps(again.records[0].views)) == sec["views"][0]["views"]


def test_team_sensing_usage_errors_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    from hil_sim.cli import main

    with pytest.raises(SystemExit) as ok:
        main(["experiment", "team-sensing", "--help"])
    assert ok.value.code == 0 and "--cycles" in capsys.readouterr().out
    assert main(["experiment", "team-sensing", "--scenes", "0"]) == 2
    assert "--scenes" in capsys.readouterr().err
    for w in ("0.5", "101", "nan"):
        assert main(["experiment", "team-sensing", "--corridor-weight", w]) == 2
        assert "--corridor-weight must be within 1-100" in capsys.readouterr().err


@pytest.mark.slow
def test_with_no_target_reachable_the_corridor_leads_toward_the_nearest() -> None:
    """Scene 7: the tethers reach no target; the corridor is the straight way toward the nearest
    one as far as the tethers hold the Cliff-bot, not its start alone."""
    import numpy as np

    from hil_sim.team.team_views_run import TeamViewsRun
    from hil_sim.world import load_scenario

    world = load_scenario("cliff-team", 7)
    run = TeamViewsRun(world, 7, team=True)
    assert not run.reachable
    start = np.asarray(world.team.cliffbot_start_xy, float)
    targets = np.asarray(world.team.targets_xyz, float)[:, :2]
    nearest = targets[int(np.argmin(np.linalg.norm(targets - start, axis=1)))]
    far = run.path[int(np.argmax(np.linalg.norm(run.path - start, axis=1)))]
    assert np.linalg.norm(far - start) > 0.3  # it leaves its start
    assert np.linalg.norm(far - nearest) < np.linalg.norm(start - nearest) - 0.3
    assert run.corridor.sum() > 0


def test_the_corridor_ratio_is_bounded_where_the_recon_bot_alone_never_gets_there() -> None:
    """Team at 95 % in 6 cycles, the RECON-bot alone not within the cap of 40: the ratio is at
    most 6 / 41 (its bound row); where both reach it, past the 12 cycles of the other figures
    too, their plain ratio; a scene the team does not finish has no bound."""
    from hil_sim.lab.experiments.experiment_team_sensing import COLUMNS, report
    from hil_sim.lab.results import markdown_table

    def row(seed: int, team: int | None, alone: int | None) -> dict[str, object]:
        r: dict[str, object] = dict.fromkeys(COLUMNS, 0.5)
        r.update(seed=seed, corridor_cycles_team=team, corridor_cycles_recon=alone, reachable=True,
                 corridor_ratio=None if team is None or alone is None else team / alone)
        return r

    md = report([row(0, 6, None), row(1, 4, 8), row(2, None, None), row(3, 10, 25)], markdown_table, 12, 40)

    def cells(key: str) -> list[str]:
        return [c.strip() for c in next(line for line in md.splitlines() if key in line).split("|")]

    bound = cells("an upper bound")
    assert "counted as 41" in bound[1]
    assert float(bound[2]) == pytest.approx(0.4) and float(bound[3]) == pytest.approx(0.5)
    both = cells("(scenes where both reach it within 40)")
    assert float(both[2]) == pytest.approx((0.5 + 0.4) / 2) and float(both[3]) == pytest.approx(0.5)
    assert cells("within 12 cycles: RECON-bot alone")[2] == "1"
    assert cells("within 40 cycles: RECON-bot alone")[2] == "2"
    assert float(cells("cycles to 95 % of the corridor: RECON-bot alone")[3]) == 25
    assert "12 cycles, or on to 95 % or 40 cycles" in cells("when the RECON-bot alone stopped")[1]


def test_a_run_goes_on_past_its_cycles_until_the_corridor_is_mapped_or_the_cap() -> None:
    """``cycles_to_corridor``: the first cycle at the fraction among the cycles run, else more
    cycles until it is reached (the run stops there) or the cap (None)."""
    from hil_sim.team.team_views_run import CycleRecord, TeamViewsRun

    class Fake:
        cycles_to_corridor = TeamViewsRun.cycles_to_corridor

        def __init__(self, fracs: list[float]) -> None:
            self.fracs = fracs
            self.records: list[CycleRecord] = []

        def cycle(self) -> CycleRecord:
            rec = CycleRecord(len(self.records) + 1, corridor_frac=self.fracs[len(self.records)])
            self.records.append(rec)
            return rec

    run = Fake([0.5, 0.9, 0.96, 0.97, 0.99])
    run.cycle()
    assert run.cycles_to_corridor(0.95, 5) == 3 and len(run.records) == 3
    assert run.cycles_to_corridor(0.95, 5) == 3 and len(run.records) == 3  # already there: no more cycles
    assert Fake([0.5] * 6).cycles_to_corridor(0.95, 4) is None


def test_the_overlap_is_reported_over_every_cycle_each_scenes_worst_and_each_scenes_mean() -> None:
    """The summary's overlap rows: the median and the worst single cycle over every cycle of every
    scene, the cycles above 0.15, and each scene's worst cycle and mean (median and worst scene)."""
    from hil_sim.lab.experiments.experiment_team_sensing import COLUMNS, report
    from hil_sim.lab.results import markdown_table

    def row(seed: int, overlaps: list[float]) -> dict[str, object]:
        r: dict[str, object] = dict.fromkeys(COLUMNS, 0.5)
        r.update(seed=seed, corridor_cycles_team=None, corridor_cycles_recon=None, corridor_ratio=None, reachable=True,
                 overlaps=overlaps, overlap_max=max(overlaps), overlap_mean=sum(overlaps) / len(overlaps),
                 overlaps_open=[o / 10 for o in overlaps])
        return r

    md = report([row(0, [0.0, 0.0, 0.6]), row(1, [0.1, 0.0, 0.0])], markdown_table, 3, 40)

    def cells(key: str) -> list[str]:
        return [c.strip() for c in next(line for line in md.splitlines() if key in line).split("|")]

    every = cells("every cycle of every scene (median of the cycles")
    assert float(every[2]) == 0.0 and float(every[3]) == pytest.approx(0.6)
    assert cells("overlap more than 0.15")[2:4] == ["1", "of 6"]
    assert float(cells("with information left")[3]) == pytest.approx(0.06)
    worst = cells("two views, each scene's worst cycle (")
    assert float(worst[2]) == pytest.approx(0.35) and float(worst[3]) == pytest.approx(0.6)
    mean = cells("each scene's mean over its cycles")
    assert float(mean[3]) == pytest.approx(0.2)


@pytest.mark.slow
def test_the_harness_finds_a_views_lips_as_its_stereo_would_and_keeps_the_points_under_them_out() -> None:
    """From the plateau over a drop whose ground behind lies within the camera's depth, a view
    finds lips (near point more than lip_min_drop_m above the far one, the drop away from the
    camera); from the face below, looking up at the lip, it finds none (the ground behind the lip
    is out of its sight). A point under a lip the map knows stays out of that map's gravity grid."""
    import numpy as np

    from fsw.core.geometry import CameraConfig, CameraPose
    from fsw.core.map.elevation_map import ElevationMap
    from fsw.core.planning.visibility import in_view
    from fsw.core.stereo.occlusion import LipGuard
    from hil_sim.team.team_views_run import TeamViewsRun
    from hil_sim.world import load_scenario

    run = TeamViewsRun(load_scenario("cliff-team", 0), 0, team=True)
    g = run.grid
    iy, ix = np.nonzero(np.isfinite(run.truth) & run.textured)
    cells = np.column_stack([g.x0 + (ix + 0.5) * g.cell, g.y0 + (iy + 0.5) * g.cell, run.truth[iy, ix]])

    def lips(pose: CameraPose, cam: CameraConfig) -> LipGuard:
        vis = in_view(pose, cam, cells)
        seen = cells[vis][run._line_of_sight(pose.t, cells[vis])]
        return LipGuard(g, *run._lips(pose, cam, seen), run.fusion.lip_min_drop_m)

    above = lips(CameraPose.from_pan_tilt(2.8, -0.9, 1.5, -math.pi / 2, math.radians(-60.0)), run.camera)
    assert above.lips >= 2 and np.all(above.toward[:, 1] < 0.0)
    below = lips(CameraPose.from_pan_tilt(3.02, -4.32, -4.75, math.pi / 2, math.radians(25.0)), run.cliff_camera)
    assert below.lips == 0
    emap = ElevationMap(g, run.fusion)
    lip = above.near[0]
    point = np.array([[lip[0], lip[1], lip[2] - 1.0], [lip[0] + 1.0, lip[1] + 1.0, lip[2] - 1.0]])
    eye = np.array([2.8, -0.9, 1.5])
    run._merge(emap, "team", "recon", eye, above, point, np.tile(np.eye(3) * 1e-4, (2, 1, 1)), None)
    assert emap.n.sum() == 1 and not emap.mapped[g.cell_index(point[:1, 0], point[:1, 1])[:2]][0]


@pytest.mark.slow
def test_the_ground_left_in_the_recon_bots_reach_counts_only_unmapped_cells_it_can_see() -> None:
    """``recon_reach_left``: of the unmapped textured cells, those some RECON-bot station behind
    the edge has in range and line of sight; the far floor is beyond it, a mapped cell never
    counts, and a cycle's views use some of it up."""
    import numpy as np

    from hil_sim.team.team_views_run import TeamViewsRun
    from hil_sim.world import load_scenario

    run = TeamViewsRun(load_scenario("cliff-team", 4), 4, team=False)
    mappable = int((np.isfinite(run.truth) & run.textured).sum())
    left = run.recon_reach_left()
    assert 0 < left < mappable  # the floor farther than the camera's range from the edge is out of reach
    run.cycle()
    after = run.recon_reach_left()
    assert after <= left - run.records[0].new_cells // 2
    run.map.n[:] = 1
    assert run.recon_reach_left() == 0


def test_the_cells_ratio_is_also_reported_over_the_first_quarter_and_half_of_the_cycles() -> None:
    """Before a scene is used up: the new cells per cycle, team / RECON-bot alone, over the first
    cycles (``_ratio_first``), and the summary's rows of them and of the ground left in reach."""
    from hil_sim.lab.experiments.experiment_team_sensing import COLUMNS, _ratio_first, report
    from hil_sim.lab.results import markdown_table

    team, alone = [900, 800, 700, 100, 50, 10, 0, 0], [400, 400, 400, 400, 300, 200, 100, 100]
    assert _ratio_first(team, alone, 2) == pytest.approx(1700 / 800)
    assert _ratio_first(team, alone, 4) == pytest.approx(2500 / 1600)
    assert _ratio_first(team, [0, 0], 2) is None

    def row(seed: int, quarter: float, half: float, left: int) -> dict[str, object]:
        r: dict[str, object] = dict.fromkeys(COLUMNS, 0.5)
        r.update(seed=seed, corridor_cycles_team=None, corridor_cycles_recon=None, corridor_ratio=None, reachable=True,
                 cells_ratio_quarter=quarter, cells_ratio_half=half, reach_left_team=left, reach_left_alone=3 * left)
        return r

    md = report([row(0, 2.0, 1.8, 40), row(1, 1.5, 1.4, 300)], markdown_table, 8, 40)

    def cells(key: str) -> list[str]:
        return [c.strip() for c in next(line for line in md.splitlines() if key in line).split("|")]

    assert [float(v) for v in cells("over the first 2 cycles")[2:4]] == [pytest.approx(1.75), pytest.approx(1.5)]
    assert [float(v) for v in cells("over the first 4 cycles")[2:4]] == [pytest.approx(1.6), pytest.approx(1.4)]
    assert [float(v) for v in cells("behind the edge (truth, any pointing): team")[2:4]] == [170, 300]
    assert [float(v) for v in cells("behind the edge (truth, any pointing): RECON-bot alone")[2:4]] == [510, 900]


def test_each_maps_share_within_2_sigma_is_taken_on_its_own_variance_and_reported() -> None:
    """``_within_2_sigma``: a cell counts when its error is within 2 sigma of the map's own
    variance; the summary gives each map's share (median, lowest and highest scene) against
    the 90-99 % band."""
    import numpy as np

    from fsw.core.geometry import MapGrid
    from fsw.core.map.elevation_map import ElevationMap
    from hil_sim.lab.experiments.experiment_team_sensing import COLUMNS, report
    from hil_sim.lab.results import markdown_table
    from hil_sim.team.team_views_run import _within_2_sigma

    m = ElevationMap(MapGrid(0.0, 0.0, 0.1, 4, 1))
    m.z[0] = [0.0, 0.19, 0.21, np.nan]
    m.var[0] = [0.01, 0.01, 0.01, np.inf]
    m.n[0] = [1, 1, 1, 0]
    truth = np.zeros((1, 4))
    assert _within_2_sigma(m, truth, m.mapped) == pytest.approx(2 / 3)  # 0.21 is beyond 2 x 0.1
    assert _within_2_sigma(m, truth, np.zeros((1, 4), bool)) is None

    def row(seed: int, share: float) -> dict[str, object]:
        r: dict[str, object] = dict.fromkeys(COLUMNS, 0.5)
        r.update(seed=seed, corridor_cycles_team=None, corridor_cycles_recon=None, corridor_ratio=None, reachable=True,
                 in2sig_recon=share)
        return r

    md = report([row(0, 0.8), row(1, 0.95), row(2, 1.0)], markdown_table, 12, 40)
    line = next(line for line in md.splitlines() if "the RECON-bot's map, cells both mapped" in line)
    assert [c.strip() for c in line.split("|")][2:5] == ["0.95", "0.800 / 1.000", "0.90-0.99"]


@pytest.mark.slow
def test_the_cliff_bot_is_rated_and_senses_with_its_flight_camera() -> None:
    """The Cliff-bot's candidates are rated, and its views sensed, with the camera its flight
    program has (``[cliffbot_sensing]``: its usable depth among the rest), not a bench camera that
    reaches farther: no cell its view measures lies beyond that depth."""
    import numpy as np

    from fsw.core.geometry import CameraPose
    from fsw.settings import load_settings
    from hil_sim.team.team_views_run import TeamViewsRun
    from hil_sim.world import load_scenario

    flight = load_settings(check_calibration=False).cliffbot_sensing
    run = TeamViewsRun(load_scenario("cliff-team", 4), 4, team=True, tv=TeamViewConfig(cliffbot_views=1))
    cam = run._cliff().camera
    assert (cam.max_range_m, cam.min_range_m, cam.width_px, cam.hfov_deg, cam.baseline_m) == (
        flight.max_range_m, flight.min_range_m, flight.width_px, flight.hfov_deg, flight.baseline_m)
    rec = run.cycle()
    view = next(v for v in rec.views if v["agent"] == "cliffbot")
    pose = CameraPose.from_pan_tilt(*view["xyz"], math.radians(view["yaw_deg"]), math.radians(view["tilt_deg"]))
    g = run.grid
    iy, ix = np.nonzero(run.by_agent["cliffbot"].mapped)  # its first view's cells
    pts = np.column_stack([g.x0 + (ix + 0.5) * g.cell, g.y0 + (iy + 0.5) * g.cell, run.truth[iy, ix]])
    depth = (pts - pose.t) @ pose.R[:, 2]
    assert len(pts) > 0 and depth.max() <= flight.max_range_m + g.cell


@pytest.mark.slow
def test_the_face_map_takes_each_view_on_its_own_with_its_camera_centre(monkeypatch: pytest.MonkeyPatch) -> None:
    """As the flight's pipeline feeds it: one merge per view (the views before the plane's fit,
    too, not pooled into one), each with its camera centre and all its points, so the face
    map's free-space, facing and slab tests run on the harness's views."""
    import numpy as np

    from fsw.core.map.face_map import FaceMap

    calls: list[tuple[object, object]] = []
    merge = FaceMap.merge_parts

    def spy(self: FaceMap, parts: object, *args: object, **kw: object) -> object:
        calls.append((kw.get("eye"), kw.get("rays")))
        return merge(self, parts, *args, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(FaceMap, "merge_parts", spy)
    run = run_scene("cliff-team", 3, team=True, cycles=3)
    assert run.face_map is not None
    views = [v for r in run.records for v in r.views]
    assert 3 * 2 < len(views) <= 3 * (1 + TeamViewConfig().cliffbot_views)
    assert len(calls) == sum(v["obtained_cells"] > 0 for v in views) > 6  # a view that sees nothing adds no points
    assert all(eye is not None and np.shape(eye) == (3,) and rays for eye, rays in calls)
