"""Messages on the Cliff-bot's software bus (topic names and payloads).

``cb_devices`` decodes the team bus into :class:`DeviceStatus`; ``cb_radio`` receives the map
(:class:`ReceivedMap`) and the RECON-bot's fixes (:class:`FixAnswer`) and sends the fix
requests (:class:`~fsw.comm.team.fix_packets.FixRequest`); ``cb_mission`` steps the sans-I/O
mission (navigation inside) and publishes the device commands
(:class:`~fsw.tasks.cliffbot_mission.Commands`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fsw.comm.team.fix_packets import Fix, NoFix
from fsw.drivers.cliffbot_devices import CliffbotDevices

CB_STATUS = "cliffbot.status"
CB_COMMANDS = "cliffbot.commands"
CB_MAP = "cliffbot.map"
CB_FIX = "cliffbot.fix"
CB_FIX_REQUEST = "cliffbot.fix_request"


@dataclass(frozen=True)
class DeviceStatus:
    """The devices' latest statuses (the sans-I/O decoder, owned by ``cb_devices``) at ``time_s``."""

    devices: CliffbotDevices
    time_s: float


@dataclass(frozen=True)
class ReceivedMap:
    """A map the link delivered and the codec decoded, heights in the team's frame."""

    map_id: int
    z: NDArray[np.float64]


@dataclass(frozen=True)
class FixAnswer:
    """The RECON-bot's answer to a fix request: a fix, or why not."""

    answer: Fix | NoFix
    reason: str = ""
