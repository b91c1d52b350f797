"""The tasks' configuration sections, as the mission modules import them: declared in the
settings layer (``fsw.sections``), so no import runs from the settings up to the tasks."""

from __future__ import annotations

from fsw.sections import CaptureConfig, MissionConfig

__all__ = ["CaptureConfig", "MissionConfig"]
