"""Flight camera driver backends: in-process (lockstep), socket (multi-process) (issue 3, item 7)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from fsw.drivers import camera as cam
from fsw.drivers.factory import DevicesConfig, close_devices, open_devices
from hil_sim.faults import FaultInjector
from hil_sim.hw.camera_server import CameraServer, SimCameraLink


def _pair(h: int = 48, w: int = 64) -> tuple[np.ndarray, np.ndarray, float]:
    rng = np.random.default_rng(1)
    return rng.integers(0, 256, (h, w), dtype=np.uint8), rng.integers(0, 256, (h, w), dtype=np.uint8), 12.5


def test_callable_source_and_sim_link_deliver_pairs() -> None:
    drv = cam.CameraDriver(cam.make_source("sim", lambda: _pair()[:2]), timeout_s=1.0)
    assert drv.trigger(0.0) == 1
    drv.poll(0.1)
    got = drv.take()
    assert got is not None and got.left.shape == (48, 64) and drv.take() is None
    link = SimCameraLink(_pair)
    drv2 = cam.CameraDriver(cam.make_source("sim", link), timeout_s=1.0)
    drv2.trigger(0.0)
    drv2.poll(0.0)
    assert drv2.take() is None  # rendered by the bench between frames, like an exposure
    link.serve(0.1)
    drv2.poll(0.1)
    pair = drv2.take()
    assert pair is not None and pair.t_capture_s == 12.5 and np.array_equal(pair.right, _pair()[1])


def test_socket_backend_against_camera_server() -> None:
    """Multi-process camera transport, dropout and a server that goes away."""
    faults = FaultInjector(0)
    server = CameraServer(_pair, faults).start()
    try:
        drv = cam.CameraDriver(cam.make_source(f"tcp://127.0.0.1:{server.address[1]}"), timeout_s=1.0)
        t = 0.0
        seq = drv.trigger(t)
        for _ in range(100):
            time.sleep(0.01)
            t += 0.01
            drv.poll(t)
            if drv.latest is not None:
                break
        assert drv.latest is not None and drv.latest.seq == seq and drv.latest.left.shape == (48, 64)
        faults.inject("camera_dropout", mode="status")
        drv.trigger(t)
        for _ in range(100):
            time.sleep(0.01)
            t += 0.01
            drv.poll(t)
            if drv.dropouts:
                break
        events = [n for n, _ in drv.drain_events()]
        assert drv.has(cam.F_DROPOUT) and "CAMERA_DROPOUT" in events
    finally:
        server.close()
    drv.trigger(t)  # the server is gone: a link error, not an exception
    t += 0.1
    drv.poll(t)
    drv.poll(t + 1.5)
    assert drv.fault and {"CAMERA_LINK_ERROR", "CAMERA_TIMEOUT"} & {n for n, _ in drv.drain_events()}
    drv.close()


def test_devices_config_refuses_bad_camera_source() -> None:
    with pytest.raises(ValueError, match="camera_source"):
        DevicesConfig(camera_source="usb:7")
    with pytest.raises(ValueError, match="port"):
        DevicesConfig(camera_source="tcp://127.0.0.1:http")


def test_absent_devices_start_faulted_and_never_raise() -> None:
    """The flight software boots without its hardware; the drivers say why."""
    devs = open_devices(
        DevicesConfig(
            can_interface="virtual",
            can_channel="absent-test",
            serial_url="/dev/does-not-exist",
            camera_source="tcp://127.0.0.1:1",
        )
    )
    try:
        mast = devs.mast
        assert mast is not None and devs.camera is not None
        mast.poll(0.0)
        assert mast.has(0x10) and any(n == "MAST_PORT_ERROR" for n, _ in mast.drain_events())
        c = devs.camera
        c.trigger(0.0)
        c.poll(0.1)
        assert c.fault
    finally:
        close_devices(devs)
