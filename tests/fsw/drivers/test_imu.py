"""The attitude sensor on CAN (issue 13, item 1): frame codec, bench device with bias and
noise, flight driver supervision (stuck, dropout, self-test, bad frames), the rover truth
tilted by the terrain under its wheels, and the attitude reaching the pose estimate."""

from __future__ import annotations

import math

import can
import numpy as np
import pytest
from hil_helpers import bench
from hypothesis import given, settings
from hypothesis import strategies as st

from fsw.comm.imu_can import ImuAttitude, ImuCan
from fsw.comm.rover_can import Bad
from fsw.core.geometry import RoverConfig
from fsw.drivers import imu_can as imu
from hil_sim.faults import FaultInjector
from hil_sim.hw.imu import ImuConfig, ImuDevice
from hil_sim.rover_truth import RoverTruth, RoverTruthConfig

CODEC = ImuCan()


class Plane:
    """Ground rising ``gx`` m/m along +x and ``gy`` along +y."""

    def __init__(self, gx: float, gy: float) -> None:
        self.gx, self.gy = gx, gy

    def height_at(self, x, y):  # type: ignore[no-untyped-def]
        return self.gx * np.asarray(x, float) + self.gy * np.asarray(y, float)


def test_frame_roundtrip_and_end_to_end_protection() -> None:
    fid, data = CODEC.encode(2.5, -3.21, 1.5, False, True, 7)
    d = CODEC.decode(fid, data)
    assert isinstance(d, ImuAttitude)
    assert (d.roll_deg, d.pitch_deg, d.counter, d.moving) == (2.5, -3.21, 7, True)
    bad = bytearray(data)
    bad[1] ^= 0x04
    assert isinstance(CODEC.decode(fid, bytes(bad)), Bad) and CODEC.decode(fid, bytes(bad)).reason == "checksum"
    assert CODEC.decode(fid, data[:5]).reason == "dlc"
    assert CODEC.decode(fid + 1, data).reason == "unknown_id"
    _, nan = CODEC.encode(math.nan, math.inf, -math.inf, False, False, 0)  # never raises
    assert isinstance(CODEC.decode(fid, nan), ImuAttitude)


@settings(max_examples=200, deadline=None)
@given(st.binary(min_size=0, max_size=12))
def test_decoding_random_bytes_never_raises(data: bytes) -> None:
    """Fuzz: any payload decodes to an attitude with a valid CRC or to a Bad, never raises."""
    d = CODEC.decode(CODEC.frame_id, data)
    assert isinstance(d, (ImuAttitude, Bad))
    if isinstance(d, ImuAttitude):
        assert len(data) == 8 and data[-1] == CODEC.encode(d.roll_deg, d.pitch_deg, d.yaw_rate_dps,
                                                           d.self_test_fail, d.moving, d.counter)[1][-1]


def _rig(gx: float, gy: float, cfg: ImuConfig, faults: FaultInjector | None = None, seed: int = 3):
    """A truth rover on a plane, its IMU device and the flight driver on a virtual bus."""
    chan = f"imu-test-{np.random.default_rng().integers(1 << 30)}"
    dev_bus = can.Bus(interface="virtual", channel=chan)
    fsw_bus = can.Bus(interface="virtual", channel=chan)
    rover = RoverTruth(Plane(gx, gy), RoverConfig(), RoverTruthConfig(), seed)
    dev = ImuDevice(dev_bus, CODEC, rover, cfg, seed, faults)
    drv = imu.ImuDriver(CODEC, timeout_s=0.3, stuck_frames=5, average_s=1.0, sigma_deg=0.1)
    return rover, dev, drv, (dev_bus, fsw_bus)


def _step(dev: ImuDevice, drv: imu.ImuDriver, bus: can.BusABC, t0: float, n: int, dt: float = 0.05) -> float:
    t = t0
    for _ in range(n):
        t += dt
        dev.faults.update(t)
        dev.transmit(t)
        while (m := bus.recv(timeout=0.0)) is not None:
            drv.on_frame(bytes(m.data), t)
        drv.poll(t)
    return t


def test_truth_rover_sits_tilted_on_a_slope() -> None:
    """The bench's true rover takes roll and pitch from the terrain under its wheels."""
    rover = RoverTruth(Plane(math.tan(math.radians(6.0)), math.tan(math.radians(4.0))), RoverConfig(),
                       RoverTruthConfig(), 0)
    assert math.degrees(rover.pitch) == pytest.approx(6.0, abs=1e-6)  # nose up on a rising x
    assert math.degrees(rover.roll) == pytest.approx(4.0, abs=1e-6)  # left (+y) side higher
    R = rover.body_rotation()
    assert R[2, 0] == pytest.approx(math.sin(math.radians(6.0)), abs=1e-9)


def test_driver_attitude_is_truth_plus_the_sensor_bias() -> None:
    """Bias: the mean of the samples is the true attitude plus the device's seeded bias, to
    within the noise over the averaged samples; the covariance states the bias sigma."""
    cfg = ImuConfig(bias_sigma_deg=0.5, noise_sigma_deg=0.2)
    rover, dev, drv, (a, b) = _rig(math.tan(math.radians(5.0)), 0.0, cfg)
    try:
        t = _step(dev, drv, b, 0.0, 40)
        att = drv.attitude(t)
        assert att is not None and att.samples == 20  # 1 s of 20 Hz frames
        tol = 4 * math.radians(0.2) / math.sqrt(att.samples) + math.radians(0.01)
        assert att.pitch == pytest.approx(rover.pitch + math.radians(dev.bias_deg[1]), abs=tol)
        assert att.roll == pytest.approx(rover.roll + math.radians(dev.bias_deg[0]), abs=tol)
        assert abs(dev.bias_deg[1]) > 0.01  # the bias is really there (seed 3)
        assert math.sqrt(att.cov[0, 0]) == pytest.approx(math.radians(0.1), rel=0.2)
        assert drv.faults == 0 and drv.rx_frames == 40
    finally:
        a.shutdown()
        b.shutdown()


@pytest.mark.parametrize("mode,bit,event", [
    ("stuck", imu.F_STUCK, "IMU_STUCK"),
    ("dropout", imu.F_TIMEOUT, "IMU_TIMEOUT"),
    ("selftest", imu.F_SELF_TEST, "IMU_SELF_TEST"),
])
def test_sensor_fault_is_detected_and_the_attitude_withheld(mode: str, bit: int, event: str) -> None:
    """Fault: a stuck sensor (frames repeated, counter frozen), a dropout and a failed
    self-test each set a fault bit and an event, and no attitude is given until it recovers."""
    faults = FaultInjector(1)
    rover, dev, drv, (a, b) = _rig(0.02, 0.01, ImuConfig(), faults)
    try:
        t = _step(dev, drv, b, 0.0, 25)
        assert drv.attitude(t) is not None
        faults.inject("imu_fault", start_s=t, duration_s=1.0, mode=mode)
        t = _step(dev, drv, b, t, 15)
        assert drv.faults & bit and drv.attitude(t) is None
        names = [e[0] for e in drv.drain_events()]
        assert event in names
        t = _step(dev, drv, b, t, 30)  # fault over: fresh frames again
        assert not drv.faults & imu.UNUSABLE and drv.attitude(t) is not None
        assert "IMU_RECOVERED" in [e[0] for e in drv.drain_events()]
    finally:
        a.shutdown()
        b.shutdown()


def test_corrupted_and_lost_frames_are_counted_not_used() -> None:
    faults = FaultInjector(2)
    _, dev, drv, (a, b) = _rig(0.0, 0.0, ImuConfig(), faults)
    try:
        faults.inject("can_corrupt", start_s=0.0, rate=0.3, target="IMU")
        faults.inject("can_drop", start_s=0.0, rate=0.2, target="IMU")
        t = _step(dev, drv, b, 0.0, 200)
        assert drv.rx_bad > 0 and drv.rx_lost > 0 and drv.rx_frames > 50
        att = drv.attitude(t)
        assert att is not None and abs(math.degrees(att.roll)) < 1.0  # no corrupted value got in
    finally:
        a.shutdown()
        b.shutdown()


def test_lockstep_attitude_reaches_the_pose_estimate_and_the_motor_driver_ignores_it() -> None:
    """On the bench the IMU frames share the motor bus: the motor driver hands them over (no
    bad frames), the devices task reports them, and nav.pose carries the attitude; a dropout
    marks it unknown (large sigma), never level-and-certain."""
    with bench() as b:
        b.run(25)
        assert int(b.tlm("can_drv.bad")) == 0 and int(b.tlm("imu_drv.frames")) >= 20
        assert int(b.tlm("imu_drv.faults")) == 0
        motion = b.exe.tasks["motion"]
        st = motion.attitude.state()
        assert st.valid and math.sqrt(st.cov[0, 0]) < math.radians(0.2)
        b.faults.inject("imu_fault", start_s=b.clock.now(), duration_s=5.0, mode="dropout")
        b.run(10)
        st = motion.attitude.state()
        assert not st.valid and math.sqrt(st.cov[0, 0]) >= math.radians(4.9)
        assert b.events(".IMU_TIMEOUT")


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.floats(-0.6, 0.6), st.floats(-0.6, 0.6)), min_size=1, max_size=40))
def test_attitude_average_is_numpys_to_the_bit(samples: list[tuple[float, float]]) -> None:
    """Issue 15: the mean and sample variance in plain floats equal numpy's (the reference
    arithmetic), and a second call in the same frame returns the same estimate."""
    drv = imu.ImuDriver(CODEC, average_s=10.0, sigma_deg=0.1)
    drv.samples.extend((0.1 * i, r, p) for i, (r, p) in enumerate(samples))
    drv.rx_frames = len(samples)
    now = 0.1 * (len(samples) - 1)
    att = drv.attitude(now)
    assert att is not None and drv.attitude(now) is att
    a = np.asarray([s[1:] for s in drv.samples])
    n = len(samples)
    var = a.var(axis=0, ddof=1) / n if n > 1 else np.full(2, drv.sigma_rad**2)
    assert (att.roll, att.pitch) == (float(a.mean(axis=0)[0]), float(a.mean(axis=0)[1]))
    assert np.array_equal(att.cov, np.diag(drv.sigma_rad**2 + var)) and att.samples == n
