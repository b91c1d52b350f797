"""The flight software's whole configuration: one frozen object built from one TOML file.

Each section's dataclass lives beside the code that uses it (the tasks' own sections in
``fsw.sections``, beside this module: the settings layer imports nothing above it); this
module only assembles them. ``load_settings(path)`` validates everything up front
(``fsw.framework.params``) so a bad file is refused with one line naming the file, the key
and the reason; that includes the stereo calibration file ``[camera] calibration_file``
names (``fsw.drivers.calibration_file``): missing or inconsistent, it is a start-up error
like any bad key.

A file is a flight configuration unless it says ``[executive] flight = false``: it must then be
complete, every section its agent reads and every key present (a left-out key is refused, not
defaulted; :func:`check_complete`), and
schedule the mission, health, console and MAVLink tasks (``schedule_check.FLIGHT_KINDS``), so a
truncated or trimmed file never flies on defaults. Bench and
ground-tool files say ``flight = false`` and may leave sections and keys out; those take the
defaults ``fsw.framework.params.describe`` lists. In both cases the schedule itself is checked
(``fsw.schedule_check.check``: known kinds, rates within design range, the tasks each task
needs).
"""

from __future__ import annotations

import typing
from dataclasses import dataclass, field
from pathlib import Path

from fsw.comm.link import LinkConfig
from fsw.comm.mavlink_config import MavlinkConfig
from fsw.comm.team.sync_config import SyncConfig
from fsw.core.codec.mapcodec import CodecConfig
from fsw.core.edge.edge import EdgeConfig
from fsw.core.edge.geofence import GeofenceConfig
from fsw.core.geometry import CameraConfig, MapGridConfig, MastConfig, RoverConfig
from fsw.core.localization.fiducials import CliffbotLayout
from fsw.core.localization.localization import LocalizationConfig
from fsw.core.map.checkpoint import CheckpointConfig
from fsw.core.map.elevation_map import FusionConfig
from fsw.core.motion.motion_profile import MotionConfig
from fsw.core.planning.nbv import NbvConfig
from fsw.core.registration.registration import RegistrationConfig
from fsw.core.stereo.calibrate import CalibrationConfig
from fsw.core.stereo.stereo import StereoConfig
from fsw.core.stereo.stereo_calibration import StereoCalibration
from fsw.core.team.cliffbot_nav import NavConfig
from fsw.core.team.climber_ground import ClimberConfig
from fsw.core.team.tether import TetherConfig
from fsw.drivers.calibration_file import CalibrationError, load_calibration
from fsw.drivers.factory import DevicesConfig
from fsw.framework.agent import AgentConfig
from fsw.framework.params import ConfigError, build, load_toml
from fsw.framework.schedule import ExecutiveConfig
from fsw.registry import AGENTS
from fsw.schedule_check import check, check_agent
from fsw.sections import (
    CaptureConfig,
    CliffbotBusConfig,
    CliffbotMissionConfig,
    CliffbotSensingConfig,
    CliffbotSiteConfig,
    MissionConfig,
)

DEFAULT_CONFIG = Path(__file__).resolve().parent.parent / "config" / "fsw.toml"


@dataclass(frozen=True)
class FswConfig:
    """Root of the flight configuration (``config/fsw.toml``)."""

    executive: ExecutiveConfig
    agent: AgentConfig = field(default_factory=AgentConfig)
    rover: RoverConfig = field(default_factory=RoverConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    mast: MastConfig = field(default_factory=MastConfig)
    map: MapGridConfig = field(default_factory=MapGridConfig)
    stereo: StereoConfig = field(default_factory=StereoConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    localization: LocalizationConfig = field(default_factory=LocalizationConfig)
    cliffbot: CliffbotLayout = field(default_factory=CliffbotLayout)
    edge: EdgeConfig = field(default_factory=EdgeConfig)
    geofence: GeofenceConfig = field(default_factory=GeofenceConfig)
    checkpoint: CheckpointConfig = field(default_factory=CheckpointConfig)
    mavlink: MavlinkConfig = field(default_factory=MavlinkConfig)
    codec: CodecConfig = field(default_factory=CodecConfig)
    link: LinkConfig = field(default_factory=LinkConfig)
    map_sync: SyncConfig = field(default_factory=SyncConfig)  # the team's two-way map sync (docs/sync.md)
    nbv: NbvConfig = field(default_factory=NbvConfig)
    devices: DevicesConfig = field(default_factory=DevicesConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    capture: CaptureConfig = field(default_factory=CaptureConfig)
    mission: MissionConfig = field(default_factory=MissionConfig)
    calibration: CalibrationConfig = field(default_factory=CalibrationConfig)
    # the Cliff-bot's (agent kind "cliffbot"; docs/team.md)
    tether: TetherConfig = field(default_factory=TetherConfig)
    climber: ClimberConfig = field(default_factory=ClimberConfig)
    cliffbot_nav: NavConfig = field(default_factory=NavConfig)
    cliffbot_mission: CliffbotMissionConfig = field(default_factory=CliffbotMissionConfig)
    cliffbot_site: CliffbotSiteConfig = field(default_factory=CliffbotSiteConfig)
    cliffbot_bus: CliffbotBusConfig = field(default_factory=CliffbotBusConfig)
    cliffbot_sensing: CliffbotSensingConfig = field(default_factory=CliffbotSensingConfig)


def calibration_path(cfg: FswConfig) -> Path | None:
    """The calibration file ``[camera] calibration_file`` names (None: no rectification)."""
    name = cfg.camera.calibration_file
    if not name:
        return None
    p = Path(name)
    return p if p.is_absolute() else DEFAULT_CONFIG.parent.parent / p


def load_stereo_calibration(cfg: FswConfig, source: str = "") -> StereoCalibration | None:
    """The camera's calibration, validated against its image size; ``ConfigError`` if it
    is missing or inconsistent (None when no file is configured)."""
    path = calibration_path(cfg)
    if path is None:
        return None
    try:
        return load_calibration(path, cfg.camera.width_px, cfg.camera.height_px)
    except CalibrationError as err:
        raise ConfigError(source or "config", "camera.calibration_file", str(err)) from None


def check_complete(data: dict[str, object], source: str) -> None:
    """A flight file lists every key of every section its agent reads (``[agent] kind``'s
    topology, ``fsw.registry.AGENTS``), and those sections only: ``ConfigError`` naming the
    first one left out."""
    hints = typing.get_type_hints(FswConfig)
    for name in ("executive", "agent", *sorted(AGENTS[_agent_kind(data)].sections)):
        if name not in data:
            raise ConfigError(source, name, "missing table (a flight configuration lists every key)")
        build(hints[name], data[name], source, name, complete=True)


def _agent_kind(data: dict[str, object]) -> str:
    """``[agent] kind`` of the raw file (its default when left out)."""
    agent = data.get("agent")
    kind = agent.get("kind", "recon") if isinstance(agent, dict) else "recon"
    return str(kind)


def load_settings(path: str | Path = DEFAULT_CONFIG, check_calibration: bool = True) -> FswConfig:
    """Load and validate a flight configuration file (and, unless ``check_calibration`` is
    false, as for the tools that make one, the calibration file it names); raises
    ``ConfigError``."""
    data = load_toml(path)
    ex = data.get("executive")
    flight = not isinstance(ex, dict) or ex.get("flight", True) is not False
    cfg = build(FswConfig, data, source=str(path))
    check_agent(cfg, set(data), str(path))
    if flight:
        check_complete(data, str(path))
    check(cfg, str(path))
    if check_calibration:
        load_stereo_calibration(cfg, str(path))
    return cfg

