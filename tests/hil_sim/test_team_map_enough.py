"""The map the RECON-bot sends is enough for the Cliff-bot's planner (docs/team.md, "Limits"):
reduced with the flight file's ``[codec]``, it keeps every hazard the planner finds on the
full map and adds few rocks of its own."""

from __future__ import annotations

import numpy as np

from fsw.core.codec.mapcodec import decode_map, encode_map
from fsw.core.geometry import MapGrid
from fsw.core.team.climber_ground import ClimberConfig, ground_layers
from fsw.settings import DEFAULT_CONFIG, load_settings
from hil_sim.world import load_scenario


def test_flight_codec_keeps_the_planners_hazards_and_adds_few_rocks() -> None:
    cfg = load_settings(DEFAULT_CONFIG)
    climber = ClimberConfig()
    world = load_scenario("cliff-team", 2)
    grid = MapGrid.from_config(world.map_grid)
    full = world.ground_on_grid(grid)
    enc = encode_map(full, cell_m=grid.cell, wheel_diameter_m=cfg.codec.wheel_m(cfg.rover.wheel_diameter_m),
                     cfg=cfg.codec)
    got = np.asarray(decode_map(enc.data).z, np.float64)
    g_full, g_got = ground_layers(full, grid, climber), ground_layers(got, grid, climber)
    assert g_full.rock.sum() > 100  # the scene has rocks (a jumble) to keep
    assert not (g_full.hazard & ~g_got.hazard & np.isfinite(got)).any()  # no hazard lost
    assert g_got.rock.sum() <= 1.2 * g_full.rock.sum()  # flat ground does not read as rocks


def test_a_rock_lost_inside_another_rocks_hazard_counts_as_lost() -> None:
    """The measure of the map's hazards lost (``compare_maps``) counts a rock the received map
    no longer reads even where the grown hazard round the rocks beside it hides it: a tether may
    not touch a rock, whatever the hazard layer says."""
    from fsw.core.team.tether import TetherConfig
    from hil_sim.lab.map_enough import compare_maps

    grid, climber = MapGrid(0.0, 0.0, 0.04, 40, 40), ClimberConfig()
    full = np.zeros((40, 40))
    full[19:22, 19:22] = 0.2  # a 12 cm block: nine rock cells
    got = full.copy()
    got[20, 20] = 0.1  # its middle no longer reads as rock; the ring round it grows the same hazard
    g_full, g_got = ground_layers(full, grid, climber), ground_layers(got, grid, climber)
    assert np.array_equal(g_full.hazard, g_got.hazard) and int((g_full.rock & ~g_got.rock).sum()) == 1
    off_map = np.array([-1.0, -1.0])  # no plan: the measure only
    cmp = compare_maps(full, got, grid, np.zeros((2, 3)), off_map, off_map[None, :], TetherConfig(), climber)
    assert cmp.hazard_cells_lost == 1


def test_the_map_is_judged_by_the_legs_the_mission_plans() -> None:
    """Held-out scene 36: on the reduced map the lattice search still finds target 1 (no margins,
    no ways), but the leg the mission plans does not: one way near the lip, a couple of
    centimetres of the reduction off, is slack at the winches' length errors. "The map was
    enough" is judged by the mission's own leg planner (``compare_maps(mission=...)``), so this
    target counts as a verdict the reduction changed."""
    from fsw.core.team.tether import anchor_points
    from hil_sim.lab.map_enough import compare_maps
    from hil_sim.team.team_run import TeamSetup

    cfg = load_settings(DEFAULT_CONFIG)
    setup = TeamSetup.from_settings(load_settings(DEFAULT_CONFIG.parent / "cliffbot.toml"))
    world = load_scenario("cliff-team", 36)
    assert world.team is not None
    grid = MapGrid.from_config(world.map_grid)
    full = world.ground_on_grid(grid)
    dec = decode_map(encode_map(full, cell_m=grid.cell, wheel_diameter_m=setup.climber.wheel_d_m, cfg=cfg.codec).data)
    got = np.asarray(dec.z, np.float64)
    anchors = anchor_points(full, grid, world.team.anchors_xy, setup.tether)
    start, target = world.team.cliffbot_start_xy, world.team.targets_xyz[:1, :2]
    lattice = compare_maps(full, got, grid, anchors, start, target, setup.tether, setup.climber)
    legs = compare_maps(full, got, grid, anchors, start, target, setup.tether, setup.climber,
                        mission=setup.mission, error_bound_m=float(dec.header.error_bound_m))
    assert lattice.reasons_full == ("",) and lattice.reasons_received == ("",) and lattice.verdicts_differ == 0
    assert legs.reasons_full == ("",) and legs.reasons_received == ("no safe path",) and legs.verdicts_differ == 1
