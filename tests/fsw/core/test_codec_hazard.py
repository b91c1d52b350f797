"""Hazard-preserving reduction (issue 25): relief and height of every obstacle survive the codec."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fsw.core.codec import hazard as hz
from fsw.core.codec import relief_hold as rh
from fsw.core.codec.mapcodec import CodecConfig, MapCodecError, decode_map, encode_map
from fsw.core.codec.mapformat import HEADER_BYTES

WHEEL = 0.2


def _rocky(seed: int, shape: tuple[int, int], cell_m: float, n_rocks: int, relief_m: float,
           noise_m: float, unknown: float) -> np.ndarray:
    """Rolling ground, round rocks (0.1..0.8 m across, up to ``relief_m`` tall), noise, holes."""
    rng = np.random.default_rng(seed)
    ny, nx = shape
    yy, xx = np.mgrid[0:ny, 0:nx] * cell_m
    z = 0.3 * np.sin(xx / 1.7 + rng.uniform(0, 6)) * np.cos(yy / 2.3) + rng.normal(0, noise_m, shape)
    for _ in range(n_rocks):
        cy, cx = rng.uniform(0, ny * cell_m), rng.uniform(0, nx * cell_m)
        r = rng.uniform(0.05, 0.4)
        h = rng.uniform(0.02, relief_m)
        d2 = ((yy - cy) ** 2 + (xx - cx) ** 2) / r**2
        z = np.maximum(z, np.where(d2 < 1, z + h * np.sqrt(np.clip(1 - d2, 0, 1)), z))
    if unknown > 0:
        z[rng.random(shape) < unknown] = np.nan
    return z.astype(np.float32)


def _hazard_threshold(z: np.ndarray, cell_m: float, h) -> np.ndarray | float:
    """The relief that makes a cell a relief hazard, as the header states it: the threshold, or
    with ``hazard_across_ground`` the threshold across the ground (per cell, in height)."""
    if not h.hazard_across_ground:
        return float(h.hazard_threshold_m)
    return rh.relief_threshold(z, cell_m, h.hazard_threshold_m, hz.disc(h.relief_disc_m, cell_m))


def _classify(z: np.ndarray, cell_m: float, h) -> hz.HazardCells:
    """The input's hazard cells as the header's rule reads them."""
    threshold = _hazard_threshold(z, cell_m, h)
    return hz.classify(z, cell_m, hz.HazardRule(h.hazard_threshold_m, h.relief_disc_m, h.step_disc_m),
                       relief_threshold=None if isinstance(threshold, float) else threshold)


def _assert_bounds(z: np.ndarray, cell_m: float, enc_data: bytes, check_steps: bool = True) -> None:
    dec = decode_map(enc_data)
    h, zd = dec.header, dec.z
    known = np.isfinite(z)
    assert np.array_equal(np.isnan(zd), ~known)
    if not known.any():
        return
    assert float(np.abs(zd[known].astype(np.float64) - z[known]).max()) <= h.error_bound_m
    r0 = hz.relief(z, cell_m, h.relief_disc_m)
    r1 = hz.relief(zd, cell_m, h.relief_disc_m)
    with np.errstate(invalid="ignore"):
        haz = known & (r0 >= _hazard_threshold(z, cell_m, h))
    loss = (r0 - r1)[known].astype(np.float64)
    assert loss.max() <= h.relief_loss_any_m + 1e-6, "relief loss beyond the stated bound"
    if haz.any():
        assert (r0 - r1)[haz].max() <= h.relief_loss_hazard_m + 1e-6, "a hazard lost relief"
        assert (zd[haz] >= z[haz]).all(), "a hazard decoded lower"
    if check_steps:
        assert _steps_kept(z, cell_m, dec).all(), "a step was lost"
        cells = _classify(z, cell_m, h)
        assert cells.step_top is not None
        if cells.step_top.size:
            s0 = cells.step.ravel()[cells.step_top].astype(np.float64)
            s1 = hz.step(dec.z, cell_m, h.step_disc_m).ravel()[cells.step_top].astype(np.float64)
            # ... a rock on a rock at most the bound less the rise, plus the slack
            assert (s0 - s1).max() <= h.error_bound_m - h.support_rise_m + h.step_slack_m + 1e-6


def _steps_kept(z: np.ndarray, cell_m: float, dec, header=None) -> np.ndarray:
    """Per step from ground (top and foot no relief hazard), whether it keeps a decoded drop
    >= the threshold and loses at most the slack; the steps and hazards as ``header`` (default
    the decoded map's) reads them."""
    h = dec.header if header is None else header
    cells = _classify(z, cell_m, h)
    assert cells.step_top is not None and cells.step_foot is not None
    s0 = cells.step.ravel()[cells.step_top].astype(np.float64)
    s1 = hz.step(dec.z, cell_m, h.step_disc_m).ravel()[cells.step_top].astype(np.float64)
    hazard_at = cells.relief_hazard.ravel()
    on_ground = ~hazard_at[cells.step_top] & ~hazard_at[cells.step_foot]
    kept = s1 >= np.maximum(h.hazard_threshold_m, s0 - h.step_slack_m) - 1e-6
    return np.asarray(kept[on_ground])


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), ny=st.integers(1, 60), nx=st.integers(1, 60),
       cell_m=st.sampled_from([0.02, 0.05, 0.1]), rocks=st.integers(0, 30),
       relief=st.floats(0.05, 1.0), noise=st.sampled_from([0.0, 0.01, 0.05]),
       unknown=st.sampled_from([0.0, 0.1, 0.5]), bound_wheels=st.sampled_from([0.25, 1.0, 2.0]),
       rise=st.sampled_from([0.0, 0.25, 0.6]), rule=st.sampled_from(["entropy", "bound"]),
       mode=st.sampled_from(["predictive", "mean"]))
def test_height_and_relief_bounds_hold_on_random_maps(seed, ny, nx, cell_m, rocks, relief, noise,
                                                       unknown, bound_wheels, rise, rule, mode):
    """Done-when 2: worst height error and worst relief loss <= the bounds the header states."""
    z = _rocky(seed, (ny, nx), cell_m, rocks, relief, noise, unknown)
    cfg = CodecConfig(support_rise_fraction=rise, split_rule=rule, leaf_value=mode)
    enc = encode_map(z, cell_m=cell_m, wheel_diameter_m=WHEEL, cfg=cfg,
                     error_bound_m=bound_wheels * WHEEL)
    _assert_bounds(z, cell_m, enc.data)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), scale=st.sampled_from([0.05, 0.5, 3.0]))
def test_bounds_hold_on_white_noise(seed, scale):
    """Done-when 2 on the worst case for the reduction: every cell independent."""
    rng = np.random.default_rng(seed)
    z = rng.normal(0, scale, (33, 47)).astype(np.float32)
    z[rng.random(z.shape) < 0.2] = np.nan
    _assert_bounds(z, 0.05, encode_map(z, cell_m=0.05, wheel_diameter_m=WHEEL).data)


def test_a_boulder_flattened_by_the_height_bound_is_kept():
    """Item 1: a 0.3 m boulder on noisy ground (wheel 0.2 m, bound 0.2 m) keeps relief and height."""
    rng = np.random.default_rng(5)
    cell = 0.03
    yy, xx = np.mgrid[0:128, 0:128] * cell
    z = rng.uniform(-0.09, 0.09, (128, 128))  # ground relief below a wheel: no obstacle
    d2 = ((yy - 1.9) ** 2 + (xx - 1.9) ** 2) / 0.12**2
    z = np.where(d2 < 1, 0.3 * np.sqrt(np.clip(1 - d2, 0, 1)) + 0.09, z).astype(np.float32)
    peak = hz.relief(z, cell, 1.05).max()
    assert peak >= 0.3
    old = decode_map(encode_map(z, cell_m=cell, wheel_diameter_m=WHEEL, cfg=CodecConfig(hazard=False)).data)
    new = decode_map(encode_map(z, cell_m=cell, wheel_diameter_m=WHEEL).data)
    c_old = hz.check_obstacles(z, old.z, cell, WHEEL, 1.05)
    c_new = hz.check_obstacles(z, new.z, cell, WHEEL, 1.05)
    assert c_new.n == 1 and c_new.kept == 1 and c_new.kept_2x == c_new.n_2x
    assert c_new.worst_peak_loss_m <= 0 and c_new.position_error_cells == 0 and c_new.footprint_kept == 1
    assert c_old.worst_peak_loss_m > c_new.worst_peak_loss_m + 0.05  # what the height bound alone lost


def test_cliff_drop_is_kept():
    """Item 1: a cliff edge (1 m drop, 75 deg face): every step >= w within one wheel diameter
    (the lip and the face) keeps its height within the stated slack; the height bound alone
    does not."""
    rng = np.random.default_rng(1)
    cell = 0.03
    y = np.arange(160) * cell
    face = np.clip((y - 2.4) * np.tan(np.radians(75)), 0, 1.0)
    z = (-face[:, None] + rng.normal(0, 0.02, (160, 120))).astype(np.float32)
    dec = decode_map(encode_map(z, cell_m=cell, wheel_diameter_m=WHEEL).data)
    old = decode_map(encode_map(z, cell_m=cell, wheel_diameter_m=WHEEL, cfg=CodecConfig(hazard=False)).data)
    c = hz.check_obstacles(z, dec.z, cell, WHEEL, 1.05)
    c_old = hz.check_obstacles(z, old.z, cell, WHEEL, 1.05)
    assert c.step_cells > 100
    assert c.worst_step_loss_m <= dec.header.step_slack_m < c_old.worst_step_loss_m
    assert c.step_kept == 1.0 and c_old.step_kept < 0.99


def test_hazard_splits_cost_bytes_but_keep_the_height_bound(viking_map):
    """The hazard rule never loosens the height bound; it only adds leaves around hazards."""
    w = float(viking_map.max() - viking_map.min()) / 8
    old = encode_map(viking_map, cell_m=0.02, wheel_diameter_m=w, cfg=CodecConfig(hazard=False))
    new = encode_map(viking_map, cell_m=0.02, wheel_diameter_m=w)
    assert new.max_error_m <= w and old.max_error_m <= w
    assert new.tree.n_leaves > old.tree.n_leaves


def _as_version_1(data: bytes) -> bytes:
    """The same container in the version-1 layout (no hazard fields), as the old encoder wrote."""
    head = bytearray(data[:48])
    head[4] = 1
    head[5] &= 1
    body = bytes(head) + data[76:HEADER_BYTES] + data[HEADER_BYTES:-4]
    return body + struct.pack("<I", zlib.crc32(body))


def test_version_1_containers_still_decode(viking_map):
    """Keep the container versioned: a version-1 map decodes to the same map, hazard fields NaN."""
    enc = encode_map(viking_map, cell_m=0.02, wheel_diameter_m=0.1, cfg=CodecConfig(hazard=False))
    v1 = _as_version_1(enc.data)
    old, new = decode_map(v1), decode_map(enc.data)
    assert old.header.version == 1 and new.header.version == 2
    assert np.array_equal(old.z, new.z) and not old.header.hazard
    assert np.isnan(old.header.relief_loss_any_m)
    body = bytearray(v1[:-4])
    body[4] = 3
    with pytest.raises(MapCodecError, match="version 3"):
        decode_map(bytes(body) + struct.pack("<I", zlib.crc32(bytes(body))))


def test_bad_hazard_fields_are_refused(viking_map):
    enc = encode_map(viking_map[:64, :64], cell_m=0.02, wheel_diameter_m=0.1)
    body = bytearray(enc.data[:-4])
    struct.pack_into("<f", body, 68, float("nan"))
    with pytest.raises(MapCodecError, match="hazard fields"):
        decode_map(bytes(body) + struct.pack("<I", zlib.crc32(bytes(body))))


def test_relief_is_the_top_hat_and_ignores_unknown_cells():
    """The relief measure: height above the disc-opened ground; unknown cells neither lower
    the ground nor carry relief."""
    z = np.zeros((60, 60), np.float32)
    z[28:32, 28:32] = 0.5  # a 0.2 m rock at 5 cm cells, narrower than the 1.05 m disc
    z[0:10, 0:10] = np.nan
    r = hz.relief(z, 0.05, 1.05)
    assert np.isnan(r[0:10, 0:10]).all()
    assert r[30, 30] == pytest.approx(0.5) and r[50, 50] == 0
    wide = np.zeros((60, 60), np.float32)
    wide[10:50, 10:50] = 0.5  # a 2 m table: wider than the disc, no relief but a step
    assert hz.relief(wide, 0.05, 1.05)[30, 30] == 0
    assert hz.step(wide, 0.05, 0.2)[10, 30] == pytest.approx(0.5)


# ---------------------------------------------------------------- relief held both ways (issue 27)
TEAM_WHEEL = 0.12  # the Cliff-bot's wheel, a quarter-wheel bound and its planner's 0.6 m rock disc
TEAM_CODEC = CodecConfig(relief_disc_m=0.6, relief_ceiling=True)
FLOAT_MARGIN_M = 1e-5  # a relief's float32 rounding at these heights, and the hold's guard


def test_a_cell_just_under_the_threshold_beside_low_ground_is_held_under_it():
    """A bump 5 mm under the threshold on flat ground: the hazard rule alone lets it rise a
    bound and its ground drop a bound (its relief ceiling 2e over it: a rock to the receiver);
    the hold keeps the ceiling under the threshold, the bump lower and its ground no lower."""
    cell, e = 0.04, 0.25 * TEAM_WHEEL
    z = np.zeros((41, 41), np.float32)
    z[20, 20] = TEAM_WHEEL - 0.005
    kernel = hz.disc(0.6, cell)
    rule = hz.HazardRule(TEAM_WHEEL, 0.6, TEAM_WHEEL)
    cells = hz.classify(z, cell, rule)
    assert not cells.relief_hazard.any()
    args = {"bound_m": e, "rise_m": 0.0, "step_slack_m": 0.5 * e + 1e-6, "threshold_m": TEAM_WHEEL}
    lo, hi = hz.step_offsets(cells, **args)
    assert rh.relief_ceiling(z, lo, hi, kernel)[20, 20] >= TEAM_WHEEL + 0.05  # what the bound allows
    lo, hi = rh.cell_offsets(z, cells, cell_m=cell, relief_disc=kernel, guard_m=1e-7, **args)
    assert rh.relief_ceiling(z, lo, hi, kernel)[20, 20] < TEAM_WHEEL
    assert hi[20, 20] < 0 and lo[20, 24] > -e  # the bump held lower, the ground beside it no lower
    assert (hi - lo).min() >= args["step_slack_m"] - 1e-12  # every interval still holds a lattice value
    dec = decode_map(encode_map(z, cell_m=cell, wheel_diameter_m=TEAM_WHEEL, cfg=TEAM_CODEC).data)
    assert float(hz.relief(dec.z, cell, 0.6).max()) < TEAM_WHEEL


def _tilted(z: np.ndarray, cell_m: float, slope_deg: float) -> np.ndarray:
    """``z`` on a plane rising along y at ``slope_deg`` (a face the receiver reads across)."""
    rise = np.arange(z.shape[0], dtype=np.float64)[:, None] * cell_m * np.tan(np.radians(slope_deg))
    return (z + rise).astype(np.float32)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), ny=st.integers(8, 48), nx=st.integers(8, 48),
       rocks=st.integers(0, 30), relief=st.floats(0.05, 0.4), noise=st.sampled_from([0.0, 0.01, 0.03]),
       unknown=st.sampled_from([0.0, 0.1]), slope_deg=st.sampled_from([0.0, 30.0, 60.0]),
       bound_wheels=st.sampled_from([0.25, 0.5]))
def test_the_hold_keeps_every_hazard_and_brings_no_cell_to_the_threshold(seed, ny, nx, rocks, relief, noise,
                                                                      unknown, slope_deg, bound_wheels):
    """On random maps (rocks on rolling ground or on a face, noise, holes): every hazard
    guarantee of the header holds (never a hazard lost, hazards read across the ground), every
    step the rule keeps is kept, and no cell the receiver reads under the threshold across the
    ground (relief x cos(slope) of the original map) decodes at or over it, unless the hold gave
    way to a step (a step cell within the reach of the discs its relief depends on: the steps
    come first)."""
    cell = 0.04
    z = _tilted(_rocky(seed, (ny, nx), cell, rocks, relief, noise, unknown), cell, slope_deg)
    enc = encode_map(z, cell_m=cell, wheel_diameter_m=TEAM_WHEEL, cfg=TEAM_CODEC,
                     error_bound_m=bound_wheels * TEAM_WHEEL)
    _assert_bounds(z, cell, enc.data, check_steps=False)
    dec = decode_map(enc.data)
    kept = _steps_kept(z, cell, dec)
    assert not (_steps_the_rule_keeps(z, cell, dec.header) & ~kept).any(), "the hold lost a step the rule keeps"
    known = np.isfinite(z)
    if not known.any():
        return
    brought, near_step = _brought_to_threshold(z, cell, dec)
    assert not (brought & ~near_step).any(), "the reduction brought a cell to the threshold"


def _steps_the_rule_keeps(z: np.ndarray, cell_m: float, h) -> np.ndarray:
    """Per step from ground (as :func:`_steps_kept` lists them), whether the hazard rule's own
    intervals (``step_offsets`` on the header's hazards, no hold) keep its drop, with a margin
    for the header's float32 fields: any map inside them keeps it."""
    cells = _classify(z, cell_m, h)
    assert cells.step_top is not None and cells.step_foot is not None
    lo, hi = hz.step_offsets(cells, bound_m=h.error_bound_m, rise_m=h.support_rise_m, step_slack_m=h.step_slack_m,
                             threshold_m=h.hazard_threshold_m)
    need = np.maximum(h.hazard_threshold_m - cells.step.ravel()[cells.step_top].astype(np.float64), -h.step_slack_m)
    keeps = lo.ravel()[cells.step_top] >= hi.ravel()[cells.step_foot] + need + 1e-6
    hazard_at = cells.relief_hazard.ravel()
    return np.asarray(keeps[~hazard_at[cells.step_top] & ~hazard_at[cells.step_foot]])


def _brought_to_threshold(z: np.ndarray, cell_m: float, dec,
                          margin_m: float = FLOAT_MARGIN_M) -> tuple[np.ndarray, np.ndarray]:
    """Known cells under the threshold across the ground (relief x cos(slope), the original
    map's) by more than ``margin_m`` (default the float32 rounding of a relief) that decode at
    or over it; and the cells whose hold may give way to a step (a step cell within the reach
    of the discs their relief depends on)."""
    import cv2

    h = dec.header
    kernel = hz.disc(h.relief_disc_m, cell_m)
    limit = h.hazard_threshold_m / rh.across_ground(z, cell_m, kernel.shape[0])
    r0, r1 = hz.relief(z, cell_m, h.relief_disc_m), hz.relief(dec.z, cell_m, h.relief_disc_m)
    cells = hz.classify(z, cell_m, hz.HazardRule(h.hazard_threshold_m, h.relief_disc_m, h.step_disc_m))
    assert cells.step_top is not None and cells.step_foot is not None
    steps = np.zeros(z.size, np.uint8)
    steps[np.concatenate([cells.step_top, cells.step_foot])] = 1
    reach = cv2.dilate(cv2.dilate(steps.reshape(z.shape), kernel), kernel).astype(bool)
    with np.errstate(invalid="ignore"):
        return np.asarray(np.isfinite(z) & (r0 < limit - margin_m) & (r1 >= limit)), reach


def test_the_hold_removes_the_rocks_the_bound_alone_makes():
    """Rocky ground reduced with the hazard rule alone shows rocks the original does not have,
    cells more than two lattice steps under the threshold brought over it; with the hold none,
    steps or not."""
    cell = 0.04
    z = _rocky(7, (32, 32), cell, 12, 0.3, 0.01, 0.0)
    brought = {}
    for on in (False, True):
        cfg = CodecConfig(relief_disc_m=0.6, relief_ceiling=on)
        enc = encode_map(z, cell_m=cell, wheel_diameter_m=TEAM_WHEEL, cfg=cfg, error_bound_m=0.25 * TEAM_WHEEL)
        dec = decode_map(enc.data)
        brought[on] = int(_brought_to_threshold(z, cell, dec, 2.0 * dec.header.step_slack_m)[0].sum())
    assert brought[False] > 0 and brought[True] == 0


@pytest.mark.parametrize("slope_deg", [45.0, 60.0])
def test_a_face_reaches_the_receiver_with_the_rocks_its_planner_reads_there_and_no_other(slope_deg):
    """A plain face: by the map's upper edge, where the relief disc is cut by the edge, the
    top-hat stands up from the face. Rows whose relief in height reaches the threshold but
    whose relief across the ground does not are no rock to the Cliff-bot's planner; were they
    relief hazards (never lower, on ground never higher) the bound could still lift them into
    rocks (at 45 deg a whole row did). With the hold the relief hazards are the planner's rocks,
    and the decoded map's rocks, as its planner reads them, are exactly the original's."""
    from fsw.core.geometry import MapGrid
    from fsw.core.team.climber_ground import ClimberConfig, ground_layers

    cell = 0.04
    z = (np.mgrid[0:40, 0:40][0] * cell * np.tan(np.radians(slope_deg))).astype(np.float32)
    grid, climber = MapGrid(0.0, 0.0, cell, 40, 40), ClimberConfig(wheel_d_m=TEAM_WHEEL, rock_disc_m=0.6)
    enc = encode_map(z, cell_m=cell, wheel_diameter_m=TEAM_WHEEL, cfg=TEAM_CODEC, error_bound_m=0.25 * TEAM_WHEEL)
    dec = decode_map(enc.data)
    assert int((hz.relief(z, cell, 0.6) >= TEAM_WHEEL).sum()) > int(ground_layers(z, grid, climber).rock.sum()) > 0
    assert np.array_equal(ground_layers(dec.z, grid, climber).rock, ground_layers(z, grid, climber).rock)
    assert dec.header.hazard_across_ground
    _assert_bounds(z, cell, enc.data)
