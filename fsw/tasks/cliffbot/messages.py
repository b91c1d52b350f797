"""Messages on the Cliff-bot's software bus (topic names and payloads).

``cb_devices`` decodes the team bus into :class:`DeviceStatus`; ``cb_radio`` receives the map
(:class:`ReceivedMap`) and the RECON-bot's fixes (:class:`FixAnswer`) and sends the fix
requests (:class:`~fsw.comm.team.fix_packets.FixRequest`); ``cb_nav`` runs the navigation
(statuses, fixes, the map the mission plans on: :class:`PlanMap`; resets the mission asks
for: :class:`NavReset`) and publishes its estimate and its verdict on each fix
(:class:`NavEstimate`); ``cb_mission`` steps the sans-I/O mission and publishes the device
commands (:class:`~fsw.tasks.cliffbot_mission.Commands`) and its requests for views
(:class:`SenseRequest`); ``cb_sensing`` takes the views, fuses them and publishes the map the
mission plans on (:class:`SensedMap`: the received map with the cells its own views made known).
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
CB_NAV = "cliffbot.nav"
CB_NAV_RESET = "cliffbot.nav_reset"
CB_PLAN_MAP = "cliffbot.plan_map"
CB_SENSE = "cliffbot.sense"
CB_SENSED_MAP = "cliffbot.sensed_map"


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
    error_bound_m: float = 0.0  # every known cell within this of the map the RECON-bot made (the codec's)


@dataclass(frozen=True)
class FixAnswer:
    """The RECON-bot's answer to a fix request: a fix, or why not."""

    answer: Fix | NoFix
    reason: str = ""


@dataclass(frozen=True)
class PlanMap:
    """The map the mission plans on (the received one, the ground under the body filled by contact):
    ``carried``, its cells no sensor measured (the plane under the body carried on), and the
    received map's error bound (a sensing task started from a checkpoint takes the map from here)."""

    version: int
    z: NDArray[np.float64]
    carried: NDArray[np.bool_] | None = None
    error_bound_m: float = 0.0


@dataclass(frozen=True)
class NavReset:
    """The estimate the navigation is to take: ``s = (x, y, yaw)``, covariance ``P`` (``seq`` counts them)."""

    seq: int
    s: NDArray[np.float64]
    P: NDArray[np.float64]


@dataclass(frozen=True)
class FixVerdict:
    """A fix and the navigation's verdict: fused (``ok``) or refused by its gate, with its NIS."""

    fix: Fix
    ok: bool
    nis: float


@dataclass(frozen=True)
class NavEstimate:
    """The navigation's estimate at ``time_s`` after ``resets`` resets, and the fixes it judged since
    its last estimate."""

    time_s: float
    s: NDArray[np.float64]
    P: NDArray[np.float64]
    resets: int
    verdicts: tuple[FixVerdict, ...] = ()


@dataclass(frozen=True)
class SenseRequest:
    """The mission asks for its own views now (``seq`` counts the requests)."""

    seq: int


@dataclass(frozen=True)
class SensedMap:
    """The map the mission plans on when the Cliff-bot senses: the received map (``map_id``,
    its codec bound) with the unknown cells its own views made known (``own_cells`` of them);
    ``sense_seq``: the last request whose views are all in it (0: none)."""

    map_id: int
    z: NDArray[np.float64]
    error_bound_m: float
    sense_seq: int
    own_cells: int
    own: NDArray[np.float64] | None = None  # its own map alone (its views; NaN unknown): its map sync layer
