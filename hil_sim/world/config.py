"""Scenario configuration: one TOML file per scenario in ``config/scenarios/``.

A scenario file has the tables ``[scenario]`` (kind, default seed and camera noise),
``[world]`` (the truth grid), ``[rover_start]``, ``[map]`` (the FSW map grid that suits the
scenario, a ``fsw.core.geometry.MapGridConfig``), ``[cliffbot]``, ``[texture]`` and one table
named after its kind (``[lab]``, ``[cliff]``, ``[mars]``, ``[file]`` or ``[terrain]``). Every key is
validated by ``fsw.framework.params.build``; a bad file is refused with ``file: key: reason``.

A scenario spec names a file and may override keys, URL-query style:
``lab``, ``mars?k=0.16``, ``cliff?cliff.drop_m=2.0``, ``file:dem.png?z_scale_m=0.001``, or
a path to any scenario ``.toml``. A bare key is looked up in the kind's own table first,
then in the other tables (it must be unambiguous).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from fsw.core.geometry import MapGridConfig
from fsw.framework.params import ConfigError, build, load_toml, param

SCENARIO_DIR = Path(__file__).resolve().parents[2] / "config" / "scenarios"
KINDS = ("lab", "cliff", "mars", "file", "terrain", "cliff_team")
MAX_TRUTH_CELLS = 30_000_000


class ScenarioError(ValueError):
    """A scenario cannot be built (unknown name, unreadable DEM, ...): one line, no traceback."""


@dataclass(frozen=True)
class ScenarioInfo:
    kind: str = param("lab", choices=KINDS, doc="which terrain generator builds the world")
    description: str = param("", doc="one line for humans")
    seed: int = param(0, lo=0, hi=2**31 - 1, doc="default seed for the CLI commands")
    noise_sigma: float = param(2.0, lo=0.0, hi=50.0, units="DN",
                               doc="default camera sensor noise (std, grey levels)")


@dataclass(frozen=True)
class TruthGridConfig:
    x_min_m: float = param(-2.0, units="m")
    x_max_m: float = param(9.0, units="m")
    y_min_m: float = param(-8.0, units="m")
    y_max_m: float = param(3.0, units="m")
    cell_m: float = param(0.01, lo=0.002, hi=0.01, units="m", doc="truth cell (1 cm or finer)")

    def __post_init__(self) -> None:
        if self.x_max_m <= self.x_min_m or self.y_max_m <= self.y_min_m:
            raise ValueError("the world needs x_max_m > x_min_m and y_max_m > y_min_m")
        if self.shape[0] * self.shape[1] > MAX_TRUTH_CELLS:
            raise ValueError(f"the truth grid {self.shape} exceeds {MAX_TRUTH_CELLS} cells")

    @property
    def shape(self) -> tuple[int, int]:
        return (round((self.y_max_m - self.y_min_m) / self.cell_m),
                round((self.x_max_m - self.x_min_m) / self.cell_m))


@dataclass(frozen=True)
class RoverStartConfig:
    x_m: float = param(0.0, units="m")
    y_m: float = param(0.0, units="m")
    yaw_deg: float = param(0.0, lo=-180.0, hi=180.0, units="deg")


@dataclass(frozen=True)
class CliffbotConfig:
    x_m: float = param(2.2, units="m", doc="footprint centre")
    y_m: float = param(-2.0, units="m")
    yaw_mode: str = param("face_rover", choices=("face_rover", "absolute"),
                          doc="face_rover: yaw = bearing to the rover start + yaw_deg")
    yaw_deg: float = param(30.0, lo=-180.0, hi=180.0, units="deg")
    length_m: float = param(0.6, lo=0.25, hi=3.0, units="m")
    width_m: float = param(0.45, lo=0.25, hi=3.0, units="m")
    height_m: float = param(0.35, lo=0.25, hi=3.0, units="m")
    marker_size_m: float = param(0.18, lo=0.05, hi=1.0, units="m", doc="black square side")
    marker_ids: tuple[int, int, int, int] = param((1, 2, 3, 4), lo=0, hi=49,
                                                  doc="DICT_4X4_50 ids: front, left, right, top")


@dataclass(frozen=True)
class TextureConfig:
    base_albedo: float = param(0.5, lo=0.05, hi=0.95)
    contrast: float = param(0.25, lo=0.0, hi=1.0, doc="relative std of the multi-scale albedo")
    spectral_slope: float = param(1.2, lo=0.0, hi=4.0, doc="albedo power spectrum |f|^-slope")
    finest_m: float = param(0.02, lo=0.002, hi=1.0, units="m", doc="shortest albedo wavelength")
    coarsest_m: float = param(3.0, lo=0.05, hi=100.0, units="m", doc="longest albedo wavelength")
    detail_contrast: float = param(0.2, lo=0.0, hi=1.0,
                                   doc="relative std of the 2.5 mm detail texture (renderer)")
    sun_azimuth_deg: float = param(135.0, lo=-360.0, hi=360.0, units="deg")
    sun_elevation_deg: float = param(50.0, lo=5.0, hi=90.0, units="deg")
    ambient: float = param(0.35, lo=0.0, hi=1.0, doc="light not from the sun (baked shading)")
    cast_shadows: bool = param(False, doc="terrain casts shadows from the sun (lit at ambient "
                                          "only; hil_sim.world.shadow)")
    textureless_albedo: float = param(0.62, lo=0.0, hi=1.0)
    textureless_regions: tuple[tuple[float, float, float, float], ...] = param(
        (), doc="regions of uniform surface where stereo finds no match: centre x, y and "
                "semi-axes along x, y (m) of an irregular ellipse; the scenario keeps them on "
                "the ground below the edge (docs/world.md)")


@dataclass(frozen=True)
class LabConfig:
    edge_y_m: float = param(-0.8, units="m", doc="mean y of the step edge")
    edge_wiggle_m: float = param(0.07, lo=0.0, hi=1.0, units="m", doc="std of its irregularity")
    edge_wavelength_m: float = param(0.8, lo=0.05, hi=20.0, units="m")
    bay_x_m: float = param(3.3, units="m", doc="centre of a bay cut into the plateau")
    bay_depth_m: float = param(0.3, lo=0.0, hi=2.0, units="m")
    bay_width_m: float = param(0.9, lo=0.1, hi=5.0, units="m")
    drop_m: float = param(0.4, lo=0.3, hi=0.5, units="m", doc="depth of the pit floor")
    face_width_m: float = param(0.05, lo=0.01, hi=0.5, units="m", doc="run of the step face")
    pit_x_min_m: float = param(-0.5, units="m")
    pit_x_max_m: float = param(7.0, units="m")
    pit_y_min_m: float = param(-6.5, units="m")
    sand_relief_m: float = param(0.012, lo=0.0, hi=0.2, units="m")
    piles: tuple[tuple[float, float, float, float], ...] = param(
        ((3.6, -3.2, 0.6, 0.3), (5.4, -2.0, 0.5, 0.25), (4.6, -5.0, 0.7, 0.35)),
        doc="rock piles: x, y, radius, height (m)")


@dataclass(frozen=True)
class CliffConfig:
    edge_y_m: float = param(-1.0, units="m")
    edge_wiggle_m: float = param(0.2, lo=0.0, hi=2.0, units="m")
    edge_wavelength_m: float = param(1.5, lo=0.05, hi=20.0, units="m")
    drop_m: float = param(1.5, lo=0.2, hi=20.0, units="m", doc="height of the cliff face")
    face_slope_deg: float = param(75.0, lo=30.0, hi=89.0, units="deg")
    face_roughness_m: float = param(0.05, lo=0.0, hi=0.5, units="m")
    floor_slope_deg: float = param(4.0, lo=0.0, hi=30.0, units="deg", doc="ground below, away")
    floor_relief_m: float = param(0.04, lo=0.0, hi=1.0, units="m")
    jumble_k: float = param(0.35, lo=0.0, hi=0.5, doc="rock coverage at the cliff foot")
    jumble_decay_m: float = param(1.5, lo=0.1, hi=20.0, units="m")
    background_k: float = param(0.05, lo=0.0, hi=0.5, doc="rock coverage far from the cliff")
    d_min_m: float = param(0.04, lo=0.01, hi=1.0, units="m")
    d_max_m: float = param(1.0, lo=0.05, hi=5.0, units="m")


@dataclass(frozen=True)
class CliffTeamConfig:
    """The ``cliff-team`` generator (hil_sim/world/cliff_team.py): -1 values are drawn from the seed."""

    face_slope_deg: float = param(-1.0, lo=-1.0, hi=85.0, units="deg", doc="face slope; -1: drawn in 55..85")
    drop_m: float = param(-1.0, lo=-1.0, hi=8.0, units="m", doc="height of the face; -1: drawn in 2..8")
    edge_y_m: float = param(-1.0, units="m", doc="mean y of the edge line")
    edge_wiggle_m: float = param(0.12, lo=0.0, hi=1.0, units="m")
    edge_wavelength_m: float = param(1.5, lo=0.05, hi=20.0, units="m")
    face_roughness_m: float = param(0.03, lo=0.0, hi=0.3, units="m", doc="face relief (horizontal std)")
    ledges: int = param(2, lo=0, hi=6, doc="shelves across the face")
    floor_slope_deg: float = param(4.0, lo=0.0, hi=30.0, units="deg")
    jumble_k: float = param(0.4, lo=0.0, hi=0.5, doc="rock coverage in the jumble on the face")
    floor_k: float = param(0.08, lo=0.0, hi=0.5, doc="rock coverage on the floor below")
    rock_d_min_m: float = param(0.08, lo=0.01, hi=1.0, units="m")
    rock_d_max_m: float = param(0.7, lo=0.05, hi=3.0, units="m")
    anchor_spacing_m: float = param(3.0, lo=0.5, hi=20.0, units="m", doc="between the two Anchorbots")
    anchor_setback_m: float = param(1.6, lo=0.3, hi=20.0, units="m", doc="anchors behind the edge")
    targets: int = param(3, lo=2, hi=4, doc="science targets on the face")

    def __post_init__(self) -> None:
        if self.rock_d_min_m >= self.rock_d_max_m:
            raise ValueError("rock_d_min_m must be below rock_d_max_m")


@dataclass(frozen=True)
class MarsConfig:
    k: float = param(0.07, lo=0.0, hi=0.5, doc="Viking rock coverage (VL1 0.07, VL2 0.16)")
    relief_m: float = param(0.05, lo=0.0, hi=2.0, units="m", doc="rolling ground std")
    relief_wavelength_m: float = param(4.0, lo=0.1, hi=100.0, units="m")
    d_min_m: float = param(0.03, lo=0.005, hi=1.0, units="m")
    d_max_m: float = param(1.5, lo=0.05, hi=5.0, units="m")
    scarp_drop_m: float = param(0.5, lo=0.0, hi=5.0, units="m",
                                doc="a low scarp below the rover's plateau; 0 = none (no edge)")
    edge_y_m: float = param(-1.0, units="m")
    edge_wiggle_m: float = param(0.15, lo=0.0, hi=2.0, units="m")
    edge_wavelength_m: float = param(1.5, lo=0.05, hi=20.0, units="m")


@dataclass(frozen=True)
class TerrainConfig:
    """The ``terrain`` generator (hil_sim/world/terrain.py): -1 / 0 values are drawn from the seed."""

    slope_deg: float = param(6.0, lo=-1.0, hi=12.0, units="deg",
                             doc="regional slope of the ground; -1: drawn in 0..12")
    slope_azimuth_deg: float = param(-1.0, lo=-1.0, hi=360.0, units="deg",
                                     doc="downhill direction, CCW from +x; -1: drawn")
    edge_distance_m: float = param(0.0, lo=0.0, hi=2.0, units="m",
                                   doc="edge to the start's footprint; 0: drawn in 0.3..2")
    edge_bearing_deg: float = param(-90.0, lo=-180.0, hi=180.0, units="deg",
                                    doc="direction of the edge from the start, CCW from the heading "
                                        "(-90: right, 0: ahead)")
    edge_wiggle_m: float = param(0.15, lo=0.0, hi=1.0, units="m", doc="std of the edge line")
    edge_wavelength_m: float = param(1.5, lo=0.1, hi=20.0, units="m")
    drop_m: float = param(1.0, lo=0.3, hi=5.0, units="m", doc="height of the cliff face")
    face_slope_deg: float = param(75.0, lo=45.0, hi=89.0, units="deg")
    relief_m: float = param(0.03, lo=0.0, hi=0.3, units="m", doc="rolling ground std")
    k: float = param(0.07, lo=0.0, hi=0.5, doc="Viking rock coverage below the edge (VL1 0.07, VL2 0.16)")
    d_min_m: float = param(0.03, lo=0.01, hi=0.5, units="m", doc="smallest rock drawn")
    d_max_m: float = param(1.0, lo=0.05, hi=3.0, units="m", doc="largest rock below the edge")
    plateau_k: float = param(0.03, lo=0.0, hi=0.5, doc="rock coverage on the plateau")
    plateau_d_max_m: float = param(0.15, lo=0.02, hi=1.0, units="m",
                                   doc="largest rock on the plateau (drivable rubble)")
    textureless_count: int = param(2, lo=0, hi=8, doc="textureless patches below the edge")


@dataclass(frozen=True)
class FileDemConfig:
    path: str = param("", doc="the DEM: .npy float32 metres or 16-bit PNG (set by the spec)")
    cell_m: float = param(0.01, lo=0.001, hi=10.0, units="m", doc="DEM cell size")
    z_scale_m: float = param(0.001, lo=1e-6, hi=100.0, units="m", doc="PNG: metres per count")
    z_offset_m: float = param(0.0, units="m", doc="added to every height")
    x_min_m: float = param(-1.0, units="m", doc="world x of the DEM's first column edge")
    y_min_m: float = param(-6.0, units="m", doc="world y of the DEM's lowest-y row edge")
    png_north_up: bool = param(True, doc="PNG row 0 is the largest y (image convention)")
    plateau_tol_m: float = param(0.05, lo=0.001, hi=10.0, units="m",
                                 doc="with plateau_max_slope_deg = 0: plateau = ground "
                                     "connected to the start within this height")
    plateau_max_slope_deg: float = param(
        35.0, lo=0.0, hi=80.0, units="deg",
        doc="plateau = ground connected to the start through steps no steeper than this "
            "(sloped ground); 0: the level rule with plateau_tol_m")
    max_abs_height_m: float = param(1000.0, lo=1.0, hi=1e5, units="m",
                                    doc="heights beyond +- this are refused (wrong units)")
    zero_at_start: bool = param(True, doc="shift the heights so the ground under the rover "
                                          "centre at the start is z = 0 (the flight map's datum "
                                          "is the body on its wheels: hil_sim.lab.terrain_eval)")


@dataclass(frozen=True)
class ScenarioConfig:
    """Root of one ``config/scenarios/*.toml`` file."""

    scenario: ScenarioInfo
    map: MapGridConfig
    world: TruthGridConfig = field(default_factory=TruthGridConfig)
    rover_start: RoverStartConfig = field(default_factory=RoverStartConfig)
    cliffbot: CliffbotConfig = field(default_factory=CliffbotConfig)
    texture: TextureConfig = field(default_factory=TextureConfig)
    lab: LabConfig | None = None
    cliff: CliffConfig | None = None
    mars: MarsConfig | None = None
    file: FileDemConfig | None = None
    terrain: TerrainConfig | None = None
    cliff_team: CliffTeamConfig | None = None


def parse_spec(spec: str) -> tuple[Path, dict[str, str], str | None]:
    """Split a scenario spec into (scenario file, overrides, DEM path or None)."""
    spec = spec.strip()
    base, _, query = spec.partition("?")
    overrides: dict[str, str] = {}
    for item in filter(None, query.split("&")):
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            raise ScenarioError(f"scenario spec {spec!r}: override {item!r} is not key=value")
        overrides[key.strip()] = value.strip()
    dem: str | None = None
    if base.startswith("file:"):
        dem = base[5:]
        if not dem:
            raise ScenarioError("scenario spec 'file:' needs a path, e.g. file:terrain.npy")
        path = SCENARIO_DIR / "file.toml"
    elif base.endswith(".toml"):
        path = Path(base)
    elif base in ("lab", "cliff", "mars", "terrain"):
        path = SCENARIO_DIR / f"{base}.toml"
    else:
        names = sorted(p.stem for p in SCENARIO_DIR.glob("*.toml") if p.stem != "file")
        if base and (SCENARIO_DIR / f"{base}.toml").is_file():
            path = SCENARIO_DIR / f"{base}.toml"
        else:
            raise ScenarioError(f"unknown scenario {base!r} (known: {', '.join(names)}, "
                                "file:PATH, or a path to a .toml)")
    return path, overrides, dem


def load_scenario_config(spec: str) -> tuple[ScenarioConfig, str | None]:
    """Read and validate the scenario named by ``spec`` with its overrides applied."""
    path, overrides, dem = parse_spec(spec)
    raw = load_toml(path)
    kind = raw.get("scenario", {}).get("kind") if isinstance(raw.get("scenario"), dict) else None
    if dem is not None:
        raw.setdefault("file", {})["path"] = dem
    for key, value in overrides.items():
        _apply_override(raw, key, value, kind, spec)
    cfg = build(ScenarioConfig, raw, source=str(path))
    return cfg, dem


def _apply_override(raw: dict[str, Any], key: str, value: str, kind: Any, spec: str) -> None:
    if "." in key:
        table, _, name = key.partition(".")
    elif kind in KINDS and name_in(str(kind), key):
        table, name = str(kind), key
    else:
        hits = [t for t in _TABLES if t not in KINDS and name_in(t, key)]
        if len(hits) != 1:
            why = "no scenario table has this key" if not hits else (
                f"ambiguous, say which table: {', '.join(h + '.' + key for h in hits)}")
            raise ConfigError(spec, key, why)
        table, name = hits[0], key
    try:
        parsed = tomllib.loads(f"v = {value}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value  # a bare string
    sub = raw.setdefault(table, {})
    if not isinstance(sub, dict):
        raise ConfigError(spec, table, "not a table")
    sub[name] = parsed


def name_in(table: str, key: str) -> bool:
    """Whether the scenario table ``table`` declares ``key``."""
    cls = _TABLES.get(table)
    return cls is not None and key in {f.name for f in fields(cls)}


_TABLES: dict[str, type] = {
    "scenario": ScenarioInfo, "map": MapGridConfig, "world": TruthGridConfig,
    "rover_start": RoverStartConfig, "cliffbot": CliffbotConfig, "texture": TextureConfig,
    "lab": LabConfig, "cliff": CliffConfig, "mars": MarsConfig, "file": FileDemConfig,
    "terrain": TerrainConfig, "cliff_team": CliffTeamConfig,
}
