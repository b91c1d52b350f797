"""The flight software's whole configuration: one frozen object built from one TOML file.

Each section's dataclass lives beside the code that uses it; this module only assembles
them. ``load_settings(path)`` validates everything up front (``fsw.config``) so a bad file
is refused with one line naming the file, the key and the reason.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from fsw.config import build, load_toml
from fsw.core.geometry import CameraConfig, MapGridConfig, MastConfig, RoverConfig
from fsw.executive.config import ExecutiveConfig

DEFAULT_CONFIG = Path(__file__).resolve().parent.parent / "config" / "fsw.toml"


@dataclass(frozen=True)
class FswConfig:
    """Root of the flight configuration (``config/fsw.toml``)."""

    executive: ExecutiveConfig
    rover: RoverConfig = field(default_factory=RoverConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    mast: MastConfig = field(default_factory=MastConfig)
    map: MapGridConfig = field(default_factory=MapGridConfig)


def load_settings(path: str | Path = DEFAULT_CONFIG) -> FswConfig:
    """Load and validate a flight configuration file; raises ``ConfigError``."""
    return build(FswConfig, load_toml(path), source=str(path))
