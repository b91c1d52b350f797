"""What the app (or a bench) hands the flight tasks: open drivers, stores and hooks, typed.

The app opens the drivers from ``[devices]`` (``fsw.drivers.factory``) into a
:class:`Resources`; a bench in the same process may bring already-open :class:`Endpoints`
(a python-can bus, a serial port, a frame source) instead, or its own radio port and the
oracle's truth. Every field is optional: a task whose device is absent starts without it and
says so (its events), never with a ``KeyError``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, BinaryIO

import numpy as np
from numpy.typing import NDArray

from fsw.framework.watchdog import Watchdog

if TYPE_CHECKING:
    import can

    from fsw.drivers.byte_port import BytePort
    from fsw.drivers.camera import CameraDriver, FrameSource
    from fsw.drivers.can_motors import CanMotorDriver
    from fsw.drivers.imu_can import ImuDriver
    from fsw.drivers.map_store import MapStore
    from fsw.drivers.mast_serial import MastSerialDriver, SerialPort


@dataclass(frozen=True)
class OracleTruth:
    """The true terrain on the map grid, for the oracle planner (docs/algorithm.md §7): only a
    bench has it."""

    z_m: NDArray[np.float64]
    textured: NDArray[np.bool_]


@dataclass
class Endpoints:
    """Already-open device ends a bench hands in, used instead of opening ``[devices]``."""

    can_bus: can.BusABC | None = None
    mast_port: SerialPort | None = None
    camera_source: FrameSource | None = None


@dataclass
class Resources:
    """The drivers and hooks of one flight-software instance."""

    motors: CanMotorDriver | None = None
    imu: ImuDriver | None = None  # the attitude sensor (on the motor bus)
    mast: MastSerialDriver | None = None
    camera: CameraDriver | None = None
    radio_port: BytePort | None = None  # the inter-robot radio (fsw.drivers.radio)
    map_store: MapStore | None = None
    watchdog: Watchdog | None = None
    mavlink_link: BytePort | None = None  # the ground link (fsw.drivers.mavlink_transport)
    mavlink_tlog: str | BinaryIO | None = None  # None: the configured path
    # Unix seconds for MAVLink signing and the .tlog's stamps; None: the host's (time.time). A
    # lockstep bench gives its stepped clock's, so a lockstep run's .tlog is the same every time.
    unix_time: Callable[[], float] | None = None
    oracle_truth: OracleTruth | None = None
    team_can: can.BusABC | None = None  # the Cliff-bot's bus to its winches, wheels, IMU (a bench's end)
    # Extra sections a mission checkpoint carries (``fsw.tasks.mission_state``): a bench puts its
    # world truth and random generators here so a lockstep resume continues the same run.
    checkpoint_hooks: dict[str, Callable[[], dict[str, object]]] = field(default_factory=dict)
