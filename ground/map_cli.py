"""``safer-map``: the map codec on the command line (docs/algorithm.md §6; docs/quadtree.md).

    safer-map encode IN.npy OUT.sqm [--wheel-diameter M] [--max-error M] [--cell-m M]
    safer-map decode IN.sqm|CHECKPOINT OUT.npy
    safer-map info IN.sqm|CHECKPOINT

Maps are ``.npy`` arrays of float32 metres, NaN = unknown. ``decode`` and ``info`` also read
the flight software's map checkpoints (``SAFERMAP``, fsw/core/map/checkpoint.py); any other
file is named in one line with the command that reads it. Defaults (wheel diameter, cell
size, codec settings) come from ``config/fsw.toml`` (``[rover]``, ``[map]``, ``[codec]``).
Bad or truncated input, or a bad config, prints one line ``safer-map: error: ...`` and
exits 2.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fsw.core.codec.hazard import check_obstacles, disc
from fsw.core.codec.mapcodec import CodecConfig, MapCodecError, decode_map, encode_map
from fsw.core.codec.relief_hold import relief_threshold
from fsw.core.geometry import MapGridConfig, RoverConfig
from fsw.core.map import checkpoint
from fsw.core.map.elevation_map import ElevationMap
from fsw.framework.params import ConfigError, build, load_toml
from fsw.settings import DEFAULT_CONFIG

PROG = "safer-map"


class UsageError(Exception):
    """Bad input: reported on one line, exit 2."""


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=PROG,
        description="Encode an elevation map (.npy float32 metres, NaN = unknown) into the "
        "compressed quadtree container sent to the Cliff-bot, decode it back, or describe it. "
        "Every known cell of the decoded map is within the error bound of the original, and "
        "every obstacle (relief >= one wheel diameter) keeps its relief and height (never lower).",
        epilog="Exit codes: 0 ok, 2 bad usage, input file or config.")
    p.add_argument("--config", default=str(DEFAULT_CONFIG),
                   help="flight config for defaults ([rover], [map], [codec])")
    sub = p.add_subparsers(dest="cmd", metavar="COMMAND", required=True)
    e = sub.add_parser("encode", help="compress a .npy map into a map container",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    e.add_argument("input", type=Path, help=".npy file, 2-D float, metres, NaN = unknown")
    e.add_argument("output", type=Path, help="container file to write")
    e.add_argument("--wheel-diameter", type=float, metavar="M",
                   help="the receiving rover's wheel diameter in metres (default: [codec] "
                   "receiver_wheel_diameter_m, or [rover] wheel_diameter_m when that is 0)")
    e.add_argument("--max-error", type=float, metavar="M",
                   help="error bound in metres (default: [codec] error_bound_wheels x wheel)")
    e.add_argument("--cell-m", type=float, metavar="M", help="cell size (default: [map] cell_m)")
    d = sub.add_parser("decode", help="rebuild the .npy map from a container or a map checkpoint")
    d.add_argument("input", type=Path, help="container file or map checkpoint")
    d.add_argument("output", type=Path, help=".npy file to write (float32, NaN = unknown)")
    i = sub.add_parser("info", help="print a container's or a map checkpoint's header and sizes")
    i.add_argument("input", type=Path, help="container file or map checkpoint")
    return p


def _read_bytes(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise UsageError(f"{path}: cannot read ({exc.strerror or exc})") from None


def _load_npy(path: Path) -> np.ndarray:
    try:
        with path.open("rb") as fh:
            head = fh.read(6)
    except OSError as exc:
        raise UsageError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if head != b"\x93NUMPY":
        raise UsageError(f"{path}: not a .npy file (bad magic)")
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise UsageError(f"{path}: not a readable .npy array ({exc})") from None
    if not isinstance(z, np.ndarray) or z.ndim != 2 or 0 in z.shape:
        raise UsageError(f"{path}: expected a non-empty 2-D array, got shape {getattr(z, 'shape', '?')}")
    if not (np.issubdtype(z.dtype, np.floating) or np.issubdtype(z.dtype, np.integer)):
        raise UsageError(f"{path}: expected float elevations, got dtype {z.dtype}")
    return z


def _positive(name: str, v: float | None) -> None:
    if v is not None and not (v > 0 and np.isfinite(v)):
        raise UsageError(f"{name} must be a positive number of metres, got {v}")


def cmd_encode(args: argparse.Namespace) -> int:
    data = load_toml(args.config)
    rover = build(RoverConfig, data.get("rover", {}), args.config, "rover")
    grid = build(MapGridConfig, data.get("map", {}), args.config, "map")
    codec = build(CodecConfig, data.get("codec", {}), args.config, "codec")
    for name in ("wheel_diameter", "max_error", "cell_m"):
        _positive("--" + name.replace("_", "-"), getattr(args, name))
    wheel = args.wheel_diameter or codec.wheel_m(rover.wheel_diameter_m)
    cell = args.cell_m or grid.cell_m
    z = _load_npy(args.input)
    try:
        enc = encode_map(z, cell_m=cell, wheel_diameter_m=wheel, cfg=codec,
                         error_bound_m=args.max_error)
    except ValueError as exc:
        raise UsageError(f"{args.input}: {exc}") from None
    try:
        args.output.write_bytes(enc.data)
    except OSError as exc:
        raise UsageError(f"{args.output}: cannot write ({exc.strerror or exc})") from None
    t = enc.tree
    print(f"{args.output}: {z.shape[0]}x{z.shape[1]} cells -> {len(enc.data)} bytes; "
          f"{t.n_leaves} leaves (reduction {t.reduction_factor:.1f}x); max error "
          f"{enc.max_error_m:.4f} m (bound {args.max_error or codec.error_bound_wheels * wheel:.4f} m)")
    threshold = codec.hazard_relief_wheels * wheel
    z32 = np.asarray(z, np.float32)
    across = codec.hazard and codec.relief_ceiling  # the reduction's hazards are read across the ground
    c = check_obstacles(z32, decode_map(enc.data).z, cell, threshold, codec.relief_disc_m, relief_threshold=(
        relief_threshold(z32, cell, threshold, disc(codec.relief_disc_m, cell)) if across else None))
    print(f"obstacles (relief {'x cos(slope) ' if across else ''}>= {threshold:.3f} m over a "
          f"{codec.relief_disc_m:g} m disc): "
          f"{c.n} given, {c.kept} kept; >= {2 * threshold:.3f} m: {c.n_2x} given, {c.kept_2x} kept; "
          f"worst relief loss on them {max(c.worst_relief_loss_m, 0.0):.4f} m; "
          f"steps >= {threshold:.3f} m: {c.step_cells} cells, {c.step_kept:.1%} kept")
    return 0


# What a file that is neither a map container nor a checkpoint is, and which command reads it.
_OTHER_KINDS = (
    (b"\x93NUMPY", "a .npy array; compress it with 'safer-map encode'"),
    (b"\x89PNG", "a PNG picture, not a map"),
    (b"\xfd\x37\x7a\x58\x5a", "an xz archive, not a map"),
)


def _checkpoint(raw: bytes, path: Path) -> tuple[ElevationMap, checkpoint.CheckpointMeta] | None:
    """The map and metadata when ``raw`` is a map checkpoint, else None; a damaged one is an error."""
    if not raw.startswith(checkpoint.MAGIC):
        return None
    try:
        return checkpoint.decode(raw)
    except checkpoint.CheckpointError as exc:
        raise UsageError(f"{path}: map checkpoint, unreadable: {exc}") from None


def _container(raw: bytes, path: Path) -> Any:
    """The decoded map container; a file of another kind is named with the command that reads it."""
    for magic, what in _OTHER_KINDS:
        if raw.startswith(magic):
            raise UsageError(f"{path}: {what}")
    if path.suffix == ".tlog":
        raise UsageError(f"{path}: a MAVLink telemetry log; 'safer-ground map' renders its map previews")
    try:
        return decode_map(raw)
    except MapCodecError as exc:
        raise UsageError(f"{path}: not a map container or checkpoint ({exc})") from None


def cmd_decode(args: argparse.Namespace) -> int:
    raw = _read_bytes(args.input)
    ck = _checkpoint(raw, args.input)
    if ck is not None:
        emap, meta = ck
        z = np.where(emap.mapped, emap.z, np.nan).astype(np.float32)
        try:
            np.save(args.output, z)
        except OSError as exc:
            raise UsageError(f"{args.output}: cannot write ({exc.strerror or exc})") from None
        print(f"{args.output}: {z.shape[0]}x{z.shape[1]} cells, {int(np.isfinite(z).sum())} known, "
              f"from checkpoint {meta.seq} at mission time {meta.time_s:.1f} s")
        return 0
    dec = _container(raw, args.input)
    try:
        np.save(args.output, dec.z)
    except OSError as exc:
        raise UsageError(f"{args.output}: cannot write ({exc.strerror or exc})") from None
    known = int(np.isfinite(dec.z).sum())
    print(f"{args.output}: {dec.header.ny}x{dec.header.nx} cells, {known} known, "
          f"max error bound {dec.header.error_bound_m:.4f} m")
    return 0


def _checkpoint_info(raw: bytes, emap: ElevationMap, meta: checkpoint.CheckpointMeta) -> None:
    g = emap.grid
    z = emap.z[emap.mapped]
    state = (meta.state or {}).get("mission") or {}
    rows = [("kind", f"map checkpoint (version {meta.version})"), ("bytes", len(raw)),
            ("seq", meta.seq), ("time_s", f"{meta.time_s:.1f}"),
            ("cells", f"{g.ny} x {g.nx} ({z.size} known)"), ("cell_m", f"{g.cell:.4g}"),
            ("origin_m", f"x {g.x0:.3f}, y {g.y0:.3f}"),
            ("elevation_m", f"{float(z.min()):.3f} .. {float(z.max()):.3f}" if z.size else "-"),
            ("mission_state", "saved" if meta.state is not None else "none (map only)")]
    rows += [(f"mission.{k}", state[k]) for k in ("phase", "step") if k in state]
    for k, v in rows:
        print(f"{k:18s} {v}")


def cmd_info(args: argparse.Namespace) -> int:
    raw = _read_bytes(args.input)
    ck = _checkpoint(raw, args.input)
    if ck is not None:
        _checkpoint_info(raw, *ck)
        return 0
    dec = _container(raw, args.input)
    h = dec.header
    known = int(np.isfinite(dec.z).sum())
    rows = [("bytes", len(raw)), ("cells", f"{h.ny} x {h.nx} ({known} known)"),
            ("cell_m", f"{h.cell_m:.4g}"), ("wheel_diameter_m", f"{h.wheel_diameter_m:.4g}"),
            ("error_bound_m", f"{h.error_bound_m:.4g}"), ("quant_step_m", f"{h.quant_step_m:.4g}"),
            ("leaves", h.n_leaves), ("reduction", f"{h.ny * h.nx / max(1, h.n_leaves):.1f}x"),
            ("split_rule", h.split_rule), ("leaf_value", h.leaf_value),
            ("bits_per_cell", f"{8 * len(raw) / (h.ny * h.nx):.4f}"), ("version", h.version)]
    if h.hazard:
        rows += [("hazard_threshold_m", f"{h.hazard_threshold_m:.4g}"),
                 ("relief_disc_m", f"{h.relief_disc_m:.4g}"), ("step_disc_m", f"{h.step_disc_m:.4g}"),
                 ("relief_loss_bound_hazards_m", f"{h.relief_loss_hazard_m:.4g} (relief "
                  f"{'x cos(slope) ' if h.hazard_across_ground else ''}>= threshold)"),
                 ("relief_loss_bound_m", f"{h.relief_loss_any_m:.4g} (any known cell)"),
                 ("support_rise_m", f"{h.support_rise_m:.4g}"), ("step_slack_m", f"{h.step_slack_m:.4g}")]
    else:
        rows.append(("relief_loss_bound_m", "not stated (height bound only)"))
    for k, v in rows:
        print(f"{k:18s} {v}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return {"encode": cmd_encode, "decode": cmd_decode, "info": cmd_info}[args.cmd](args)
    except (UsageError, MapCodecError, ConfigError) as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
