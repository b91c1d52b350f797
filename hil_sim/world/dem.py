"""The ``file:PATH`` scenario: any user elevation model, with a texture generated for it.

Accepted files: ``.npy`` (a 2-D float array of metres, ``[iy, ix]`` with row 0 at the lowest
``y``, as ``fsw.core.geometry.MapGrid``) or a 16-bit grayscale ``.png`` (metres =
``count * z_scale_m + z_offset_m``; row 0 is the largest ``y`` when ``png_north_up``). The DEM
is placed with its corner at ``(x_min_m, y_min_m)``; DEMs coarser than 1 cm are resampled
(bilinear) to 1 cm or finer. The rover starts at ``[rover_start]``; the plateau is the ground
connected to it within ``plateau_tol_m`` of its height, and the true edge is that plateau's
boundary (walked with the plateau on its left). The map grid covers the DEM, in the flight
map's frame (the rover's odometry from its start: :func:`start_frame_map`).

Bad files are refused with one line (:class:`ScenarioError`): a file that is not what its
suffix says (checked by its signature before any parser reads it), a ``.npy`` holding Python
objects, NaN or infinite heights, and heights beyond ``max_abs_height_m`` (wrong units).
The array size is checked from the file's header before anything is allocated: a ``.npy``
header or PNG ``IHDR`` claiming more than ``MAX_DEM_CELLS`` cells, or a ``.npy`` shorter than
its header says, is refused (a hostile header never asks for gigabytes).
With ``zero_at_start`` (default) the heights are shifted so that the ground under the rover
start is ``z = 0``. (The flight map's datum is the body resting on its four wheels, which on
rocky ground differs from that by centimetres; ``hil_sim.lab.terrain_eval`` compares in the
flight's datum.) On sloped ground the plateau is the ground
connected to the start through steps no steeper than ``plateau_max_slope_deg`` (0: the level
rule, within ``plateau_tol_m`` of the start height).
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import MapGridConfig
from hil_sim.world.build import TruthGrid, finish_world, plateau_mask, slope_plateau
from hil_sim.world.config import MAX_TRUTH_CELLS, FileDemConfig, ScenarioConfig, ScenarioError
from hil_sim.world.world import World

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
MAX_CELL_M = 0.01
START_ROOM_M = 0.6  # the rover's wheels reach 0.56 m from its centre (config/fsw.toml [rover])


MAX_DEM_CELLS = MAX_TRUTH_CELLS  # a DEM is resampled to the truth grid, which is capped at this
NPY_MAGIC = b"\x93NUMPY"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def read_dem(fc: FileDemConfig) -> F32:
    """The DEM in metres, ``[iy, ix]`` with row 0 at the lowest ``y``; ScenarioError if bad.

    The file must be what its name says (the NumPy or PNG signature in its first bytes, read
    before any parser sees it), hold finite heights, and stay within ``max_abs_height_m``.
    """
    path = Path(fc.path)
    if not path.is_file():
        raise ScenarioError(f"{path}: DEM file not found")
    suffix = path.suffix.lower()
    _check_signature(path, suffix)
    _check_size(path, suffix)
    if suffix == ".npy":
        try:
            arr = np.load(path, allow_pickle=False)
        except ValueError as exc:
            why = ("it holds Python objects (pickled data), not a numeric array"
                   if "pickle" in str(exc) else str(exc))
            raise ScenarioError(f"{path}: not a readable .npy array: {why}") from None
        except (OSError, EOFError) as exc:
            raise ScenarioError(f"{path}: not a readable .npy array ({exc})") from None
        if arr.ndim != 2 or arr.dtype.kind not in "fiu":
            raise ScenarioError(f"{path}: expected a 2-D numeric array, got {arr.dtype} "
                                f"with shape {arr.shape}")
        dem = arr.astype(np.float64) + fc.z_offset_m
    elif suffix == ".png":
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise ScenarioError(f"{path}: not a readable PNG")
        if img.ndim != 2 or img.dtype != np.uint16:
            raise ScenarioError(f"{path}: expected a 16-bit grayscale PNG, got {img.dtype} "
                                f"with shape {img.shape}")
        dem = img.astype(np.float64) * fc.z_scale_m + fc.z_offset_m
        if fc.png_north_up:
            dem = dem[::-1].copy()
    else:
        raise ScenarioError(f"{path}: unsupported DEM type {suffix!r} (use .npy or 16-bit .png)")
    if min(dem.shape) < 8:
        raise ScenarioError(f"{path}: DEM {dem.shape} is too small (at least 8 x 8)")
    finite = np.isfinite(dem)
    if not finite.all():
        raise ScenarioError(f"{path}: DEM has NaN or infinite heights ({int((~finite).sum())} "
                            f"of {dem.size} cells)")
    worst = float(np.abs(dem).max())
    if worst > fc.max_abs_height_m:
        raise ScenarioError(f"{path}: DEM height {worst:.6g} m is beyond the sane range "
                            f"+-{fc.max_abs_height_m:g} m (wrong units? set z_scale_m / "
                            f"z_offset_m, or raise max_abs_height_m)")
    return dem.astype(np.float32)


def _check_signature(path: Path, suffix: str) -> None:
    """ScenarioError unless the file starts with the signature its suffix promises."""
    magic = {".npy": NPY_MAGIC, ".png": PNG_MAGIC}.get(suffix)
    if magic is None:
        return
    with path.open("rb") as fh:
        head = fh.read(len(magic))
    if head != magic:
        kind = "NumPy .npy" if suffix == ".npy" else "PNG"
        raise ScenarioError(f"{path}: not a {kind} file (its first bytes are {head[:8]!r}, "
                            f"not the {kind} signature)")


def _check_size(path: Path, suffix: str) -> None:
    """ScenarioError if the header claims more than ``MAX_DEM_CELLS`` cells (or more bytes than
    a ``.npy`` holds); read before any array is allocated."""
    if suffix == ".npy":
        try:
            with path.open("rb") as fh:
                version = np.lib.format.read_magic(fh)
                if version == (1, 0):
                    shape, _fortran, dtype = np.lib.format.read_array_header_1_0(fh)
                elif version == (2, 0):
                    shape, _fortran, dtype = np.lib.format.read_array_header_2_0(fh)
                else:
                    raise ValueError(f"unsupported .npy format version {version}")
                offset = fh.tell()
        except (ValueError, OSError, EOFError, SyntaxError) as exc:
            raise ScenarioError(f"{path}: not a readable .npy header ({exc})") from None
        cells = math.prod(shape)
        if cells > MAX_DEM_CELLS:
            raise ScenarioError(f"{path}: .npy header claims shape {shape} ({cells:,} cells), more than "
                                f"{MAX_DEM_CELLS:,}")
        need = offset + cells * dtype.itemsize
        if dtype.hasobject or need > path.stat().st_size:
            why = "it holds Python objects" if dtype.hasobject else f"{path.stat().st_size} bytes, header needs {need}"
            raise ScenarioError(f"{path}: not a readable .npy array ({why})")
    elif suffix == ".png":
        with path.open("rb") as fh:
            head = fh.read(24)
        if len(head) < 24 or head[12:16] != b"IHDR":
            raise ScenarioError(f"{path}: not a readable PNG (no IHDR header)")
        w, h = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
        if w * h > MAX_DEM_CELLS:
            raise ScenarioError(f"{path}: PNG header claims {w} x {h} pixels, more than {MAX_DEM_CELLS:,}")


def build_from_dem(cfg: ScenarioConfig, seed: int) -> World:
    fc = cfg.file or FileDemConfig()
    if not fc.path:
        raise ScenarioError("file scenario needs a path: file:PATH")
    dem = read_dem(fc)
    factor = max(1, math.ceil(fc.cell_m / MAX_CELL_M - 1e-9))
    ny, nx = dem.shape[0] * factor, dem.shape[1] * factor
    if ny * nx > MAX_TRUTH_CELLS or max(ny, nx) >= 32767:
        raise ScenarioError(f"{fc.path}: DEM {dem.shape} at {fc.cell_m} m would need a "
                            f"{ny} x {nx} truth grid at 1 cm (too large; crop it)")
    if factor > 1:
        dem = np.asarray(cv2.resize(dem, (nx, ny), interpolation=cv2.INTER_LINEAR), np.float32)
    grid = TruthGrid(fc.x_min_m, fc.y_min_m, fc.cell_m / factor, nx, ny)
    rs = cfg.rover_start
    ix, iy = int((rs.x_m - grid.x0) / grid.cell_m), int((rs.y_m - grid.y0) / grid.cell_m)
    if not (0 <= ix < nx and 0 <= iy < ny):
        raise ScenarioError(f"{fc.path}: the rover start ({rs.x_m}, {rs.y_m}) is outside the "
                            f"DEM (x {grid.x0}..{grid.x0 + nx * grid.cell_m:.2f}, "
                            f"y {grid.y0}..{grid.y0 + ny * grid.cell_m:.2f})")
    room = int(math.ceil(START_ROOM_M / grid.cell_m))
    if not (room <= ix < nx - room and room <= iy < ny - room):
        raise ScenarioError(f"{fc.path}: the rover start ({rs.x_m}, {rs.y_m}) is within "
                            f"{START_ROOM_M} m of the DEM's border: no room for its wheels")
    if fc.zero_at_start:  # the ground under the rover centre at the start is z = 0
        dem = dem - dem[iy, ix]
    plateau_z = float(dem[iy, ix])
    if fc.plateau_max_slope_deg > 0:
        plateau = slope_plateau(grid, dem, (rs.x_m, rs.y_m), fc.plateau_max_slope_deg)
    else:
        plateau = plateau_mask(grid, dem, (rs.x_m, rs.y_m), plateau_z, fc.plateau_tol_m)
    edge = plateau_edge(plateau, grid)
    map_grid = start_frame_map(grid, nx, ny, cfg.map.cell_m, (rs.x_m, rs.y_m, math.radians(rs.yaw_deg)))
    rng = np.random.default_rng([seed, 4])
    return finish_world(cfg, f"file:{Path(fc.path).name}", seed, grid, dem, rng,
                        edge_xy=edge, plateau_z=plateau_z, map_grid=map_grid,
                        plateau=plateau)


def start_frame_map(grid: TruthGrid, nx: int, ny: int, cell: float,
                    start: tuple[float, float, float]) -> MapGridConfig:
    """The map grid covering the DEM, in the flight map's frame (the rover's odometry, which
    starts at ``start``: x, y, yaw in rad): the DEM's corners seen from the start, their
    bounding box (the DEM itself for a start at the origin facing +x)."""
    x1, y1 = grid.x0 + nx * grid.cell_m, grid.y0 + ny * grid.cell_m
    c, s = math.cos(start[2]), math.sin(start[2])
    if abs(s) < 1e-9 and c > 0:  # no turn: the DEM shifted by the start, its size as it is
        return MapGridConfig(origin_x_m=grid.x0 - start[0], origin_y_m=grid.y0 - start[1], cell_m=cell,
                             nx=max(2, min(8192, int(nx * grid.cell_m / cell))),
                             ny=max(2, min(8192, int(ny * grid.cell_m / cell))))
    dx = np.array([grid.x0, x1, x1, grid.x0]) - start[0]
    dy = np.array([grid.y0, grid.y0, y1, y1]) - start[1]
    u, v = c * dx + s * dy, -s * dx + c * dy
    return MapGridConfig(origin_x_m=float(u.min()), origin_y_m=float(v.min()), cell_m=cell,
                         nx=max(2, min(8192, int(float(np.ptp(u)) / cell))),
                         ny=max(2, min(8192, int(float(np.ptp(v)) / cell))))


def plateau_edge(plateau: NDArray[np.bool_], grid: TruthGrid) -> F64:
    """The plateau's boundary inside the DEM as one polyline with the plateau on its left
    (the longest boundary run that does not follow the DEM's border); ``(0, 2)`` if none."""
    mask = plateau.astype(np.uint8)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return np.zeros((0, 2))
    pts = max(contours, key=len)[:, 0, :]  # (N, 2) as (ix, iy)
    ny, nx = plateau.shape
    inner = (pts[:, 0] > 0) & (pts[:, 0] < nx - 1) & (pts[:, 1] > 0) & (pts[:, 1] < ny - 1)
    if not inner.any():
        return np.zeros((0, 2))
    # Longest cyclic run of inner points.
    shift = int(np.argmin(inner)) if not inner.all() else 0
    run_pts, flags = np.roll(pts, -shift, axis=0), np.roll(inner, -shift)
    edges = np.diff(np.concatenate([[0], flags.astype(np.int8), [0]]))
    starts, ends = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]
    longest = int(np.argmax(ends - starts))
    s0, length = int(starts[longest]), int(ends[longest] - starts[longest])
    seg = run_pts[s0:s0 + length].astype(float)
    xy = np.column_stack([grid.x0 + (seg[:, 0] + 0.5) * grid.cell_m,
                          grid.y0 + (seg[:, 1] + 0.5) * grid.cell_m])
    step = max(1, round(0.02 / grid.cell_m))
    xy = xy[::step]
    if len(xy) >= 2:
        mid = len(xy) // 2
        d = xy[min(mid + 1, len(xy) - 1)] - xy[max(mid - 1, 0)]
        left = np.array([-d[1], d[0]]) / max(np.hypot(*d), 1e-12)
        probe = xy[mid] + 3 * grid.cell_m * left
        jx, jy = int((probe[0] - grid.x0) / grid.cell_m), int((probe[1] - grid.y0) / grid.cell_m)
        if not (0 <= jx < nx and 0 <= jy < ny and plateau[jy, jx]):
            xy = xy[::-1]
    return np.asarray(xy, float)
