"""Map codec: quadtree reduction, predictive coding and zstandard (docs/algorithm.md §6.3-6.5).

``encode_map`` reduces the map to its quadtree of interest regions (``fsw.core.codec.quadtree``),
puts every known leaf's value on a lattice of step ``q`` (a fraction of the error bound),
codes the values as residuals from a coarse-to-fine prediction (``fsw.core.codec.hint``) and
packs three streams, tree split flags, known/unknown leaf flags and residuals, into one
zstandard frame inside a versioned container (``fsw.core.codec.mapformat``). ``decode_map``
rebuilds the elevation map on the Cliff-bot.

**Guarantee.** Every known cell of the decoded map is within ``error_bound_m`` of the
original (default one wheel diameter); every unknown cell decodes as NaN. With ``hazard =
true`` (default) every cell also has its own interval (``fsw.core.codec.hazard``): a cell
whose relief (top-hat over ``relief_disc_m``) is at least one wheel diameter decodes with
its relief and height never lower (with ``relief_ceiling``, relief across the ground:
``fsw.core.codec.relief_hold``), so no obstacle is flattened from both sides; the
relief loss bounds are in the container header. The quadtree only accepts a leaf whose
known cells' intervals share a lattice value, the encoder picks the leaf's value from that
feasible set, and ``encode_map`` checks every cell against its interval before it returns.

**(choice) Leaf values.** The paper sends each leaf's mean. With ``leaf_value =
"predictive"`` (default) the encoder sends, among the lattice values that honour the bound,
the one nearest the decoder's prediction (a rate-aware quantiser, as in trellis
quantisation), so most residuals are zero; ``"mean"`` sends the lattice value nearest the
mean of the decimated map. Both honour the same bound.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fsw.core.codec import hazard as hz
from fsw.core.codec import hint
from fsw.core.codec import relief_hold as rh
from fsw.core.codec.mapformat import Header, MapCodecError, compressor, pack, unpack
from fsw.core.codec.quadtree import Quadtree, build_quadtree, tree_depth
from fsw.core.codec.tileformat import TileProfile, pack_tile, unpack_tile
from fsw.framework.params import param

F32 = NDArray[np.float32]
I64 = NDArray[np.int64]

__all__ = ["CodecConfig", "DecodedMap", "EncodedMap", "MapCodecError", "TileProfile", "decode_map", "decode_tile",
           "encode_map", "encode_tile", "tile_profile"]

LEAF_VALUE_MODES = ("predictive", "mean")
SPLIT_RULES = ("entropy", "bound")


@dataclass(frozen=True)
class CodecConfig:
    """Map reduction and coding (``[codec]`` in config/fsw.toml). Wheel diameter: ``[rover]``."""

    error_bound_wheels: float = param(
        1.0, lo=0.01, hi=10.0, units="wheel diameters",
        doc="guaranteed max |decoded - original| on every known cell")
    quant_step_fraction: float = param(
        0.5, lo=0.05, hi=1.0, doc="leaf value lattice step as a fraction of the error bound (with hazard "
                                  "on, at most 0.5: a hazard's one-sided interval must hold a lattice value)")
    lowpass_sigma_cells: float = param(1.0, lo=0.0, hi=20.0, units="cells",
                                       doc="Gaussian low-pass before the reduction (§6.1)")
    decimation_height_wheels: float = param(
        0.5, lo=0.0, hi=5.0, units="wheel diameters",
        doc="bumps/pits narrower than a wheel and lower than this are decimated (§6.2)")
    split_rule: str = param("entropy", choices=SPLIT_RULES,
                            doc="entropy: paper Eq. 1-2 rule plus bound; bound: bound only")
    leaf_value: str = param("predictive", choices=LEAF_VALUE_MODES,
                            doc="predictive: lattice value nearest the prediction; mean: nearest the mean")
    zstd_level: int = param(17, lo=1, hi=22,
                            doc="zstandard level of the lossless stage (19: -0.4 % bytes, 4x slower)")
    max_cells: int = param(1 << 24, lo=4, hi=1 << 28, units="cells",
                           doc="largest map the decoder accepts")
    hazard: bool = param(True, doc="keep every hazard's relief (fsw.core.codec.hazard); false: height bound only")
    hazard_relief_wheels: float = param(
        1.0, lo=0.05, hi=10.0, units="wheel diameters",
        doc="relief (top-hat) or step that makes a cell critical")
    relief_disc_m: float = param(1.05, lo=0.01, hi=20.0, units="m",
                                 doc="top-hat disc diameter: about the rover's footprint")
    step_disc_wheels: float = param(1.0, lo=0.1, hi=20.0, units="wheel diameters",
                                    doc="a step is the height above the lowest cell within this disc")
    support_rise_fraction: float = param(
        0.0, lo=0.0, hi=0.9, doc="support cells rise at most, relief hazards rise at least, "
        "this fraction of the error bound")
    relief_ceiling: bool = param(
        False, doc="hold relief both ways: relief hazards are read across the ground (relief x cos(slope), as "
        "the receiver's planner reads a rock) and a cell under that threshold decodes under it too, where the "
        "steps leave room (fsw.core.codec.relief_hold)")
    receiver_wheel_diameter_m: float = param(
        0.12, lo=0.0, hi=2.0, units="m",
        doc="wheel diameter of the agent the map is sent to (the Cliff-bot: 2 x its 0.06 m wheel radius); "
        "the error bound and the hazard threshold are in these wheel diameters; 0: the sender's [rover] wheel")

    def __post_init__(self) -> None:
        if self.hazard and self.quant_step_fraction > 0.5:
            raise ValueError(f"quant_step_fraction {self.quant_step_fraction} is over 0.5 with hazard on: a "
                             "hazard's cell may only rise (or only fall) within the bound, an interval half "
                             "as wide, which a coarser lattice can miss")

    def wheel_m(self, own_wheel_m: float) -> float:
        """The wheel diameter the map is reduced for: the receiver's, or ``own_wheel_m`` (the
        sending rover's ``[rover] wheel_diameter_m``) when ``receiver_wheel_diameter_m`` is 0."""
        return self.receiver_wheel_diameter_m if self.receiver_wheel_diameter_m > 0 else own_wheel_m


@dataclass(frozen=True)
class EncodedMap:
    """The container bytes plus what the encoder measured."""

    data: bytes
    tree: Quadtree
    max_error_m: float  # realised, over known cells
    rms_error_m: float


@dataclass(frozen=True)
class DecodedMap:
    z: F32  # metres, NaN = unknown
    header: Header


def encode_map(
    z: NDArray[np.floating], *, cell_m: float, wheel_diameter_m: float,
    cfg: CodecConfig | None = None, error_bound_m: float | None = None,
) -> EncodedMap:
    """Encode an elevation map (metres, NaN = unknown). ``error_bound_m`` overrides the config."""
    cfg = cfg or CodecConfig()
    header, streams, tree, max_err, rms = _reduce(z, cell_m=cell_m, wheel_diameter_m=wheel_diameter_m, cfg=cfg,
                                                  error_bound_m=error_bound_m, lattice_offset=False)
    data = pack(header, streams, compressor(cfg.zstd_level))
    return EncodedMap(data=data, tree=tree, max_error_m=max_err, rms_error_m=rms)


def _reduce(
    z: NDArray[np.floating], *, cell_m: float, wheel_diameter_m: float, cfg: CodecConfig,
    error_bound_m: float | None, lattice_offset: bool,
) -> tuple[Header, list[bytes], Quadtree, float, float]:
    """The reduction and coding of :func:`encode_map` up to the raw streams: (header, the four
    streams, the tree, max and RMS error). ``lattice_offset``: the height offset is a whole
    number of lattice steps (the compact tile format sends that number)."""
    z32 = np.asarray(z, dtype=np.float32)
    if z32.ndim != 2 or z32.size == 0:
        raise ValueError(f"expected a non-empty 2-D map, got shape {z32.shape}")
    if z32.size > cfg.max_cells:
        raise ValueError(f"map of {z32.size} cells exceeds max_cells={cfg.max_cells}")
    if np.isinf(z32).any():
        raise ValueError("map contains infinite elevations (use NaN for unknown cells)")
    bound = float(error_bound_m if error_bound_m is not None else cfg.error_bound_wheels * wheel_diameter_m)
    if not bound > 0:
        raise ValueError("error bound must be positive")
    known = np.isfinite(z32)
    maxabs = float(np.abs(z32[known]).max()) if known.any() else 0.0
    # Keep a margin for the float32 rounding of the decoded values (one ulp at the map's scale).
    margin = 2.0 * float(np.spacing(np.float32(max(maxabs, 1.0)))) + 1e-9 * bound
    if margin >= 0.5 * bound:
        raise ValueError(f"error bound {bound} m is below float32 resolution at {maxabs} m")
    offset = float(np.mean(z32[known], dtype=np.float64)) if known.any() else 0.0
    lo_c = hi_c = lo_chk = hi_chk = None
    hazard_fields: dict[str, Any] = {}
    if cfg.hazard:
        rise = cfg.support_rise_fraction * bound
        q = cfg.quant_step_fraction * (bound - rise)  # a relief hazard's interval holds 2 steps
        slack = q + 4.0 * margin  # a step hazard that is also support keeps a lattice value
        if margin >= 0.25 * (bound - rise):
            raise ValueError(f"error bound {bound} m is below float32 resolution at {maxabs} m")
        rule = hz.HazardRule(threshold_m=cfg.hazard_relief_wheels * wheel_diameter_m,
                             relief_disc_m=cfg.relief_disc_m,
                             step_disc_m=cfg.step_disc_wheels * wheel_diameter_m)
        # With the hold, a relief hazard is what the receiver reads as one: relief across the ground.
        kernel = hz.disc(rule.relief_disc_m, cell_m) if cfg.relief_ceiling else None
        under = None if kernel is None else rh.relief_threshold(z32, cell_m, rule.threshold_m, kernel)
        cells = hz.classify(z32, cell_m, rule, relief_threshold=under)
        lo_off, hi_off = rh.cell_offsets(
            z32, cells, bound_m=bound, rise_m=rise, step_slack_m=slack, threshold_m=rule.threshold_m, cell_m=cell_m,
            relief_disc=kernel, guard_m=margin, under=under)
        z64 = z32.astype(np.float64)
        lo_c, hi_c = z64 + lo_off + margin, z64 + hi_off - margin  # the margins absorb float32 rounding
        lo_chk, hi_chk = z64 + lo_off, z64 + hi_off  # what the decoded float32 values must meet
        hazard_fields = {"hazard_threshold_m": rule.threshold_m, "relief_disc_m": rule.relief_disc_m,
                         "step_disc_m": rule.step_disc_m, "support_rise_m": rise, "step_slack_m": slack,
                         "relief_loss_hazard_m": 0.0, "relief_loss_any_m": 2.0 * bound,
                         "hazard_across_ground": cfg.relief_ceiling}
    else:
        q = cfg.quant_step_fraction * bound
    if lattice_offset:
        offset = round(offset / q) * q
    tree = build_quadtree(
        z32, wheel_diameter_m=wheel_diameter_m, cell_m=cell_m, error_bound_m=bound - margin,
        quant_step_m=q, z_offset_m=offset, lowpass_sigma_cells=cfg.lowpass_sigma_cells,
        decimation_height_m=cfg.decimation_height_wheels * wheel_diameter_m,
        split_rule=cfg.split_rule, cell_lo_m=lo_c, cell_hi_m=hi_c)
    kn = tree.leaf_known
    with np.errstate(invalid="ignore"):
        c_lo = np.where(kn, np.ceil((tree.leaf_lo_m - offset) / q), 0).astype(np.int64)
        c_hi = np.where(kn, np.floor((tree.leaf_hi_m - offset) / q), 0).astype(np.int64)
        c_mean = np.where(kn, np.rint((tree.leaf_mean_m - offset) / q), 0).astype(np.int64)
    if np.any(c_lo > c_hi):  # the quadtree guarantees this never happens
        raise AssertionError("quadtree leaf without a feasible lattice value")
    c_mean = np.clip(c_mean, c_lo, c_hi)
    lid = tree.leaf_id_map()
    codes, residuals = _run_prediction(tree, lid, mode=cfg.leaf_value, c_lo=c_lo, c_hi=c_hi,
                                       c_mean=c_mean)
    rec = np.where(kn[lid], (offset + codes[lid] * q).astype(np.float32), np.float32(np.nan))
    err = np.abs(rec[known].astype(np.float64) - z32[known])
    max_err = float(err.max()) if err.size else 0.0
    if max_err > bound or np.isfinite(rec[~known]).any():
        raise AssertionError(f"codec bound violated: {max_err} > {bound}")
    if lo_chk is not None and hi_chk is not None:
        r64 = rec[known].astype(np.float64)
        if (r64 < lo_chk[known]).any() or (r64 > hi_chk[known]).any():
            raise AssertionError("codec hazard interval violated")
    header = Header(
        ny=tree.shape[0], nx=tree.shape[1], cell_m=cell_m, wheel_diameter_m=wheel_diameter_m,
        error_bound_m=bound, quant_step_m=q, z_offset_m=offset, n_leaves=tree.n_leaves,
        has_unknown=bool((~known).any()), split_rule=cfg.split_rule, leaf_value=cfg.leaf_value,
        hazard=cfg.hazard, **hazard_fields)
    streams = _streams(tree, residuals, header.has_unknown)
    rms = float(np.sqrt(np.mean(err**2))) if err.size else 0.0
    return header, streams, tree, max_err, rms


def _run_prediction(
    tree: Quadtree, lid: NDArray[np.int32], *, mode: str,
    c_lo: I64 | None = None, c_hi: I64 | None = None, c_mean: I64 | None = None,
    residuals: I64 | None = None,
) -> tuple[I64, I64]:
    """Visit the cells coarse to fine; encode (bounds given) or decode (residuals given).

    Returns (leaf codes, residuals in send order). Unknown cells carry their prediction, so
    they never break the prediction of their neighbours.
    """
    ny, nx = tree.shape
    flat_lid = lid.ravel()
    lvl = tree.leaf_level.astype(np.int64)
    known = tree.leaf_known
    is_anchor = np.zeros(ny * nx, bool)
    is_anchor[((tree.leaf_iy << lvl) * nx + (tree.leaf_ix << lvl))[known]] = True
    values = np.zeros(ny * nx + 1, np.int64)  # last slot: out-of-map neighbour, stays 0
    codes = np.zeros(tree.n_leaves, np.int64)
    out: list[I64] = []
    pos = 0
    for step in hint.visit_order((ny, nx)):
        pts = step.pts
        leaf = flat_lid[pts]
        pred = hint.predict(values, step)
        anchor = is_anchor[pts]
        if anchor.any():
            a_leaf = leaf[anchor]
            a_pred = pred[anchor]
            if residuals is None:
                assert c_lo is not None and c_hi is not None and c_mean is not None
                target = np.clip(a_pred, c_lo[a_leaf], c_hi[a_leaf]) if mode == "predictive" \
                    else c_mean[a_leaf]
                out.append(target - a_pred)
                codes[a_leaf] = target
            else:
                n = a_leaf.size
                if pos + n > residuals.size:
                    raise MapCodecError("residual stream shorter than the tree needs")
                codes[a_leaf] = a_pred + residuals[pos:pos + n]
                pos += n
        values[pts] = np.where(known[leaf], codes[leaf], pred)
    if residuals is not None and pos != residuals.size:
        raise MapCodecError("residual stream longer than the tree needs")
    res = np.concatenate(out) if out else np.zeros(0, np.int64)
    return codes, res if residuals is None else residuals


def _streams(tree: Quadtree, residuals: I64, has_unknown: bool) -> list[bytes]:
    flags = [tree.split[lv][tree.exists[lv]] for lv in range(tree.n_levels, 0, -1)]
    split_bits = np.packbits(np.concatenate(flags)) if flags else np.zeros(0, np.uint8)
    known_bits = np.packbits(tree.leaf_known) if has_unknown else np.zeros(0, np.uint8)
    zz = (residuals << 1) ^ (residuals >> 63)
    if zz.size and int(zz.max()) >= 1 << 32:
        raise ValueError("map relief too large for this error bound (residual overflow)")
    esc = zz >= 255
    small = np.where(esc, 255, zz).astype(np.uint8)
    return [split_bits.tobytes(), known_bits.tobytes(), small.tobytes(),
            zz[esc].astype("<u4").tobytes()]


def decode_map(data: bytes, *, max_cells: int = CodecConfig().max_cells) -> DecodedMap:
    """Rebuild the map from container bytes; bad or truncated input raises MapCodecError."""
    header, streams = unpack(data, max_cells=max_cells)
    z = _rebuild(streams, (header.ny, header.nx), has_unknown=header.has_unknown, leaf_value=header.leaf_value,
                 q=header.quant_step_m, off=header.z_offset_m, n_leaves=header.n_leaves)
    return DecodedMap(z=z, header=header)


def _rebuild(streams: list[bytes], shape: tuple[int, int], *, has_unknown: bool, leaf_value: str, q: float,
             off: float, n_leaves: int | None) -> F32:
    """The map from its four raw streams (``n_leaves``: the count the tree must have, if known)."""
    split_b, known_b, small_b, esc_b = streams
    ny, nx = shape
    L = tree_depth((ny, nx))
    split_bits = np.unpackbits(np.frombuffer(split_b, np.uint8))
    exists: list[NDArray[np.bool_]] = [np.zeros(0, bool)] * (L + 1)
    split: list[NDArray[np.bool_]] = [np.zeros(0, bool)] * (L + 1)
    exists[L] = np.ones((1, 1), bool)
    pos = 0
    for lv in range(L, -1, -1):
        split[lv] = np.zeros_like(exists[lv])
        if lv > 0:
            n = int(exists[lv].sum())
            if pos + n > split_bits.size:
                raise MapCodecError("tree structure stream is truncated")
            split[lv][exists[lv]] = split_bits[pos:pos + n].astype(bool)
            pos += n
            h, w = -(-ny // (1 << (lv - 1))), -(-nx // (1 << (lv - 1)))
            exists[lv - 1] = np.repeat(np.repeat(split[lv], 2, axis=0), 2, axis=1)[:h, :w]
    if split_bits.size - pos >= 8 or split_bits[pos:].any():
        raise MapCodecError("tree structure stream has trailing data")
    lv_l, iy_l, ix_l = [], [], []
    for lv in range(L, -1, -1):
        iy, ix = np.nonzero(exists[lv] & ~split[lv])
        lv_l.append(np.full(iy.size, lv, np.int8))
        iy_l.append(iy)
        ix_l.append(ix)
    leaf_level = np.concatenate(lv_l)
    if n_leaves is not None and leaf_level.size != n_leaves:
        raise MapCodecError(f"tree has {leaf_level.size} leaves, header says {n_leaves}")
    n_leaves = leaf_level.size
    if has_unknown:
        kb = np.unpackbits(np.frombuffer(known_b, np.uint8))
        if kb.size < n_leaves or kb.size - n_leaves >= 8:
            raise MapCodecError("known-leaf stream has the wrong length")
        leaf_known = kb[:n_leaves].astype(bool)
    else:
        leaf_known = np.ones(n_leaves, bool)
    small = np.frombuffer(small_b, np.uint8).astype(np.int64)
    esc = small == 255
    big = np.frombuffer(esc_b, "<u4").astype(np.int64) if len(esc_b) % 4 == 0 else None
    if big is None or big.size != int(esc.sum()):
        raise MapCodecError("residual escape stream has the wrong length")
    zz = small.copy()
    zz[esc] = big
    residuals = (zz >> 1) ^ -(zz & 1)
    nan = np.full(n_leaves, np.nan)
    tree = Quadtree(shape=(ny, nx), n_levels=L, exists=tuple(exists), split=tuple(split),
                    leaf_level=leaf_level, leaf_iy=np.concatenate(iy_l).astype(np.int64),
                    leaf_ix=np.concatenate(ix_l).astype(np.int64), leaf_known=leaf_known,
                    leaf_mean_m=nan, leaf_lo_m=nan, leaf_hi_m=nan)
    lid = tree.leaf_id_map()
    codes, _ = _run_prediction(tree, lid, mode=leaf_value, residuals=residuals)
    with np.errstate(over="ignore", invalid="ignore"):
        heights = (off + codes[lid] * q).astype(np.float32)
    known_cells = leaf_known[lid]
    if not np.isfinite(heights[known_cells]).all():
        raise MapCodecError("decoded heights overflow: the header's offset and step do not fit the codes")
    return np.where(known_cells, heights, np.float32(np.nan)).astype(np.float32)


# ------------------------------------------------------------------ the compact tile format
def tile_profile(cfg: CodecConfig, *, cell_m: float, wheel_diameter_m: float, frame: int, shape: tuple[int, int],
                 origin: tuple[float, float], tile_cells: int) -> TileProfile:
    """The profile of the tiles an agent reduces with ``cfg`` for a wheel of ``wheel_diameter_m``
    on the grid ``shape`` / ``cell_m`` / ``origin`` of map frame ``frame`` (docs/sync.md)."""
    f32 = np.float32
    wheel = float(f32(wheel_diameter_m))
    bound = float(f32(cfg.error_bound_wheels * wheel))  # as the profile's bytes hold it
    if cfg.hazard:  # the lattice step exactly as _reduce makes it from that bound
        q = cfg.quant_step_fraction * (bound - cfg.support_rise_fraction * bound)
    else:
        q = cfg.quant_step_fraction * bound
    return TileProfile(frame=frame, ny=shape[0], nx=shape[1], cell_m=cell_m, x0=origin[0], y0=origin[1],
                       tile_cells=tile_cells, wheel_diameter_m=wheel, error_bound_m=bound, quant_step_m=q,
                       hazard=cfg.hazard, split_rule=cfg.split_rule, leaf_value=cfg.leaf_value,
                       hazard_threshold_m=cfg.hazard_relief_wheels * wheel,
                       relief_disc_m=cfg.relief_disc_m).rounded()


def encode_tile(z: NDArray[np.floating], profile: TileProfile, cfg: CodecConfig) -> bytes:
    """One tile (at most ``tile_cells`` a side) in the compact tile format of ``profile``: the
    same reduction and bound as :func:`encode_map`, without the container header."""
    header, streams, _tree, _e, _r = _reduce(z, cell_m=profile.cell_m, wheel_diameter_m=profile.wheel_diameter_m,
                                             cfg=cfg, error_bound_m=profile.error_bound_m, lattice_offset=True)
    if header.quant_step_m != profile.quant_step_m:
        raise ValueError(f"the codec's lattice step {header.quant_step_m} is not its tile profile's "
                         f"{profile.quant_step_m}")
    steps = round(header.z_offset_m / header.quant_step_m)
    return pack_tile(header.has_unknown, steps, streams, cfg.zstd_level)


def decode_tile(data: bytes, profile: TileProfile, shape: tuple[int, int]) -> F32:
    """A tile of ``shape`` cells from its compact bytes and its profile; bad input raises
    ``MapCodecError`` (one line)."""
    ny, nx = shape
    if not (1 <= ny <= profile.tile_cells and 1 <= nx <= profile.tile_cells):
        raise MapCodecError(f"a {ny}x{nx} tile is not one of the profile's {profile.tile_cells}-cell tiles")
    has_unknown, steps, streams = unpack_tile(data, ny * nx)
    q = profile.quant_step_m
    return _rebuild(streams, (ny, nx), has_unknown=has_unknown, leaf_value=profile.leaf_value, q=q,
                    off=steps * q, n_leaves=None)
