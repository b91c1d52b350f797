"""The flight software's whole configuration: one frozen object built from one TOML file.

Each section's dataclass lives beside the code that uses it; this module only assembles
them. ``load_settings(path)`` validates everything up front (``fsw.framework.params``) so a bad file
is refused with one line naming the file, the key and the reason.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from fsw.comm.link import LinkConfig
from fsw.comm.mavlink_config import MavlinkConfig
from fsw.core.checkpoint import CheckpointConfig
from fsw.core.edge import EdgeConfig
from fsw.core.elevation_map import FusionConfig
from fsw.core.fiducials import CliffbotLayout
from fsw.core.geofence import GeofenceConfig
from fsw.core.geometry import CameraConfig, MapGridConfig, MastConfig, RoverConfig
from fsw.core.localization import LocalizationConfig
from fsw.core.mapcodec import CodecConfig
from fsw.core.motion_profile import MotionConfig
from fsw.core.nbv import NbvConfig
from fsw.core.registration import RegistrationConfig
from fsw.core.stereo import StereoConfig
from fsw.drivers.factory import DevicesConfig
from fsw.framework.params import build, load_toml
from fsw.framework.schedule import ExecutiveConfig
from fsw.tasks.sections import CaptureConfig, MissionConfig

DEFAULT_CONFIG = Path(__file__).resolve().parent.parent / "config" / "fsw.toml"


@dataclass(frozen=True)
class FswConfig:
    """Root of the flight configuration (``config/fsw.toml``)."""

    executive: ExecutiveConfig
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
    nbv: NbvConfig = field(default_factory=NbvConfig)
    devices: DevicesConfig = field(default_factory=DevicesConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    capture: CaptureConfig = field(default_factory=CaptureConfig)
    mission: MissionConfig = field(default_factory=MissionConfig)


def load_settings(path: str | Path = DEFAULT_CONFIG) -> FswConfig:
    """Load and validate a flight configuration file; raises ``ConfigError``."""
    return build(FswConfig, load_toml(path), source=str(path))
