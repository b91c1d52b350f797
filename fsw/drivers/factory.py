"""Device configuration (``[devices]``) and the factory that opens the flight drivers from it.

The same flight code runs on the rover and on the bench; only these strings differ:

==================  ==========================  ==========================================
key                 rover                       bench
==================  ==========================  ==========================================
``can_interface``   ``socketcan`` (``can0``)    ``virtual`` (lockstep), ``udp_hub`` (processes)
``serial_url``      ``/dev/ttyS1``              ``/dev/pts/N`` (pty), ``socket://H:P``
``camera_source``   ``cv:0,1``                  ``sim`` (lockstep), ``tcp://H:P``
==================  ==========================  ==========================================

:func:`open_devices` opens the drivers into the typed ``Resources`` (``motors``, ``imu`` (the
attitude sensor on the motor bus), ``mast``, ``camera``). A bench in the same process may hand
in already-open ``Endpoints`` (a CAN bus, a serial port, a frame source), which are used
instead of opening the configured ones. Opening never raises for an absent device: the driver
starts faulted and retries (its events say why), so the flight software boots without its
hardware.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from fsw.drivers.resources import Endpoints, Resources
from fsw.framework.params import ConfigError, param

T = TypeVar("T")

REPO_ROOT = Path(__file__).resolve().parent.parent.parent


@dataclass(frozen=True)
class DevicesConfig:
    """Where the flight drivers find their hardware, and their timeouts."""

    can_interface: str = param(
        "none", choices=("none", "virtual", "udp_hub", "udp_multicast", "socketcan"),
        doc="python-can interface of the motor bus",
    )
    can_channel: str = param(
        "safer", doc="virtual: bus name; udp_hub: the bench's hub HOST:PORT; udp_multicast: group address; "
        "socketcan: can0"
    )
    can_udp_port: int = param(43113, lo=1024, hi=65535, doc="udp_multicast port")
    can_multicast_interface: str = param(
        "", doc="udp_multicast: the network interface the group is joined and sent on (required: lo, eth1, ...)"
    )
    can_dbc: str = param("config/rover.dbc", doc="CAN database (relative paths: to the repository root)")
    can_status_timeout_s: float = param(0.5, lo=0.05, hi=60.0, units="s", doc="no STATUS for this long: fault")
    can_heartbeat_timeout_s: float = param(2.5, lo=0.1, hi=60.0, units="s", doc="no heartbeat: node lost")
    can_heartbeat_period_s: float = param(1.0, lo=0.05, hi=60.0, units="s", doc="flight computer heartbeat")
    can_command_refresh_s: float = param(
        0.2, lo=0.0, hi=0.25, units="s",
        doc="an unchanged axis COMMAND is re-sent at least this often (a change goes out at once); at most half "
        "the controllers' command timeout (0.5 s), so a lost or late frame cannot trip it; 0 = every frame",
    )
    can_e2e_max_delta: int = param(
        3, lo=1, hi=4, doc="E2E alive counter: largest accepted jump (frames lost + 1); beyond, the frame is refused "
        "(above 4, a 1-3 bit error could move the counter across a freshness epoch unseen)"
    )
    serial_url: str = param("none", doc="mast port: device or pty path, socket://HOST:PORT, loop://, none")
    serial_baud: int = param(115200, lo=1200, hi=4000000, units="bit/s")
    mast_ack_timeout_s: float = param(0.3, lo=0.01, hi=10.0, units="s", doc="wait for ACK before a retry")
    mast_retries: int = param(3, lo=0, hi=20, doc="retransmissions before a command is given up")
    mast_state_timeout_s: float = param(1.0, lo=0.05, hi=60.0, units="s", doc="no STATE report: fault")
    imu: bool = param(True, doc="the attitude sensor (IMU_ATTITUDE) on the CAN bus")
    imu_timeout_s: float = param(0.5, lo=0.02, hi=60.0, units="s", doc="no valid IMU frame: attitude unknown")
    imu_stuck_frames: int = param(5, lo=2, hi=1000, doc="frames with a frozen alive counter: stuck sensor")
    imu_average_s: float = param(1.0, lo=0.0, hi=60.0, units="s", doc="attitude = mean of the samples this old")
    imu_sigma_deg: float = param(0.1, lo=0.0, hi=10.0, units="deg", doc="attitude bias sigma (calibration)")
    camera_source: str = param("none", doc="none | sim | tcp://HOST:PORT | cv:LEFT,RIGHT")
    camera_timeout_s: float = param(2.0, lo=0.05, hi=60.0, units="s", doc="no pair after a trigger: fault")
    error_hold_s: float = param(2.0, lo=0.0, hi=600.0, units="s", doc="a transient error flag stays this long")
    reconnect_period_s: float = param(2.0, lo=0.1, hi=600.0, units="s", doc="retry period for absent devices")

    def __post_init__(self) -> None:
        if self.can_interface == "udp_hub":
            from fsw.drivers.can_udp import parse_channel

            parse_channel(self.can_channel)
        if self.can_interface == "udp_multicast" and not self.can_multicast_interface:
            raise ValueError("udp_multicast needs can_multicast_interface (the interface to put the bus on, e.g. lo); "
                             "the bench's processes share CAN through udp_hub")
        cs = self.camera_source
        if not (cs in ("none", "sim") or cs.startswith(("tcp://", "cv:"))):
            raise ValueError(f"camera_source {cs!r}: expected none, sim, tcp://HOST:PORT or cv:LEFT,RIGHT")
        if cs.startswith("tcp://") and not cs.rpartition(":")[2].isdigit():
            raise ValueError(f"camera_source {cs!r}: the port must be a number")


def dbc_path(cfg: DevicesConfig) -> Path:
    p = Path(cfg.can_dbc)
    return p if p.is_absolute() else REPO_ROOT / p


def can_bus_kwargs(cfg: DevicesConfig) -> dict[str, Any]:
    """Keyword arguments of ``can.Bus`` for the configured interface."""
    kw: dict[str, Any] = {"interface": cfg.can_interface, "channel": cfg.can_channel}
    if cfg.can_interface == "udp_multicast":
        kw.update(port=cfg.can_udp_port, fd=False, interface_name=cfg.can_multicast_interface)
    return kw


def _provided_or_open(provided: T | None, opener: Callable[[], T]) -> tuple[T | None, Exception | None]:
    """The endpoint a bench handed in, else a freshly opened one; if opening fails, no endpoint
    and the error (the driver then starts faulted and retries)."""
    if provided is not None:
        return provided, None
    try:
        return opener(), None
    except Exception as exc:  # noqa: BLE001 - the driver starts faulted and retries
        return None, exc


def open_devices(cfg: DevicesConfig, res: Resources | None = None, endpoints: Endpoints | None = None) -> Resources:
    """Open the configured drivers into ``res`` (``motors``, ``imu``, ``mast``, ``camera``), using
    the bench's ``endpoints`` where it brought them; a driver already in ``res`` is kept."""
    import can

    from fsw.comm.imu_can import ImuCan
    from fsw.comm.rover_can import RoverCan
    from fsw.drivers.camera import CameraDriver, make_source
    from fsw.drivers.can_inproc import open_bus as open_can_bus
    from fsw.drivers.can_motors import CanMotorDriver
    from fsw.drivers.imu_can import ImuDriver
    from fsw.drivers.mast_serial import MastSerialDriver, SerialPort

    res = res or Resources()
    ends = endpoints or Endpoints()
    if res.motors is None and (cfg.can_interface != "none" or ends.can_bus is not None):

        def open_bus() -> can.BusABC:
            return open_can_bus(**can_bus_kwargs(cfg))

        try:
            codec = RoverCan(dbc_path(cfg))
        except ValueError as exc:  # unreadable, or a frame without the E2E convention (docs/hil.md)
            raise ConfigError(str(dbc_path(cfg)), "devices.can_dbc", str(exc).split(": ", 1)[-1]) from None
        bus, error = _provided_or_open(ends.can_bus, open_bus)
        res.motors = CanMotorDriver(
            bus,
            codec,
            status_timeout_s=cfg.can_status_timeout_s,
            heartbeat_timeout_s=cfg.can_heartbeat_timeout_s,
            heartbeat_period_s=cfg.can_heartbeat_period_s,
            error_hold_s=cfg.error_hold_s,
            reconnect_period_s=cfg.reconnect_period_s,
            e2e_max_delta=cfg.can_e2e_max_delta,
            command_refresh_s=cfg.can_command_refresh_s,
            opener=None if ends.can_bus is not None else open_bus,
        )
        if error is not None:
            res.motors._event("CAN_NO_BUS", error=f"{type(error).__name__}: {error}")
        if cfg.imu and res.imu is None:
            res.imu = ImuDriver(ImuCan(dbc_path(cfg)), timeout_s=cfg.imu_timeout_s, stuck_frames=cfg.imu_stuck_frames,
                                average_s=cfg.imu_average_s, sigma_deg=cfg.imu_sigma_deg, error_hold_s=cfg.error_hold_s)
            res.imu.attach(res.motors)
    if res.mast is None and (cfg.serial_url != "none" or ends.mast_port is not None):

        def open_port() -> SerialPort:
            import serial

            port: SerialPort = serial.serial_for_url(
                cfg.serial_url, baudrate=cfg.serial_baud, timeout=0, write_timeout=0.1
            )
            return port

        port, perr = _provided_or_open(ends.mast_port, open_port)
        res.mast = MastSerialDriver(
            port,
            ack_timeout_s=cfg.mast_ack_timeout_s,
            retries=cfg.mast_retries,
            state_timeout_s=cfg.mast_state_timeout_s,
            error_hold_s=cfg.error_hold_s,
            reconnect_period_s=cfg.reconnect_period_s,
            opener=None if ends.mast_port is not None else open_port,
            name=cfg.serial_url if ends.mast_port is None else "bench",
        )
        if perr is not None:
            res.mast._event("MAST_PORT_ERROR", port=cfg.serial_url, error=f"{type(perr).__name__}: {perr}")
    if res.camera is None and cfg.camera_source != "none":
        try:
            source = make_source(cfg.camera_source, ends.camera_source)
            cerr = None
        except Exception as exc:  # noqa: BLE001 - e.g. an OpenCV device that is absent
            source, cerr = None, exc
        res.camera = CameraDriver(source, cfg.camera_timeout_s, cfg.error_hold_s)
        if cerr is not None:
            res.camera._event("CAMERA_LINK_ERROR", error=f"{type(cerr).__name__}: {cerr}")
    return res


def close_devices(res: Resources) -> None:
    """Close the drivers :func:`open_devices` made (idempotent), and finish the map store's
    queued checkpoint writes."""
    if res.map_store is not None:
        res.map_store.close()
    for drv in (res.imu, res.motors, res.mast, res.camera):
        if drv is not None:
            with contextlib.suppress(Exception):  # best effort at shutdown
                drv.close()
