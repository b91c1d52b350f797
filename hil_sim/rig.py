"""The bench's hardware rig: world truth and hardware models stepped together.

One :class:`HardwareRig` holds the true rover and mast (physics, terrain) and, apart from
them, the hardware models that turn that truth into bytes: the twelve CAN motor controllers,
the CAN attitude sensor (:mod:`hil_sim.hw.imu`), the serial mast controller and the camera
(a render function of the true camera pose). Both
bench modes use it: the lockstep bench (:mod:`hil_sim.bench`) steps it between executive
frames; ``safer-hil serve`` steps it in real time. Hardware parameters come from
``config/hil_hardware.toml`` (:class:`HardwareConfig`).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import numpy as np

from fsw.comm.imu_can import ImuCan
from fsw.comm.rover_can import RoverCan
from fsw.core.geometry import CameraPose
from fsw.framework.params import build, load_toml
from fsw.settings import FswConfig
from hil_sim.camera_model import CameraModelConfig, TrueCameras
from hil_sim.faults import FaultInjector
from hil_sim.hw.imu import ImuConfig, ImuDevice
from hil_sim.hw.mast_controller import MastController, MastControllerConfig
from hil_sim.hw.motor_controllers import MotorControllerBank, MotorControllerConfig
from hil_sim.mast_truth import MastTruth, MastTruthConfig
from hil_sim.rover_truth import FlatTerrain, RoverTruth, RoverTruthConfig

DEFAULT_HARDWARE = Path(__file__).resolve().parent.parent / "config" / "hil_hardware.toml"


@dataclass(frozen=True)
class HardwareConfig:
    """Parameters of the simulated hardware (``config/hil_hardware.toml``)."""

    rover: RoverTruthConfig = field(default_factory=RoverTruthConfig)
    mast: MastTruthConfig = field(default_factory=MastTruthConfig)
    motors: MotorControllerConfig = field(default_factory=MotorControllerConfig)
    mast_controller: MastControllerConfig = field(default_factory=MastControllerConfig)
    camera: CameraModelConfig = field(default_factory=CameraModelConfig)
    imu: ImuConfig = field(default_factory=ImuConfig)


def load_hardware(path: str | Path = DEFAULT_HARDWARE) -> HardwareConfig:
    """Load and validate the hardware config; raises ``ConfigError``."""
    return build(HardwareConfig, load_toml(path), source=str(path))


class HardwareRig:
    """True rover + mast and their CAN, serial and camera models."""

    def __init__(
        self,
        world: Any,
        fsw: FswConfig,
        hw: HardwareConfig,
        seed: int,
        can_bus: can.BusABC,
        serial_port: Any,
        faults: FaultInjector | None = None,
        dbc: str | Path | None = None,
    ) -> None:
        self.world, self.fsw, self.hw, self.seed = world, fsw, hw, seed
        self.faults = faults or FaultInjector(seed)
        terrain = world if world is not None else FlatTerrain()
        start = tuple(getattr(world, "rover_start", (0.0, 0.0, 0.0)))
        self.rover = RoverTruth(terrain, fsw.rover, hw.rover, seed, start)  # type: ignore[arg-type]
        self.mast = MastTruth(fsw.mast, hw.mast, seed + 1)
        self.codec = RoverCan(dbc) if dbc is not None else RoverCan()
        self.motors = MotorControllerBank(can_bus, self.codec, self.rover, hw.motors, self.faults)
        self.imu = ImuDevice(can_bus, ImuCan(dbc) if dbc is not None else ImuCan(), self.rover, hw.imu,
                             seed, self.faults)
        self.motors.ignore_ids.add(self.imu.codec.frame_id)  # its frames echo back on an echoing bus
        self.mast_ctrl = MastController(serial_port, self.mast, hw.mast_controller, self.faults)
        self.lock = threading.Lock()
        self.now = 0.0
        self._renderer: Any = None
        self.start_pose = self.rover.pose
        self.faults_seen: list[dict[str, Any]] = []  # bench faults: {t_s, kind, detail}
        self.wheels_off_terrain_steps = 0  # rig steps with any wheel off the world's terrain
        self._off_before = False

    def step(self, now: float, dt_s: float) -> None:
        """Advance the hardware to ``now``: read commands, move the truth ``dt_s``, report."""
        with self.lock:
            self.faults.update(now)
            self.motors.receive(now)
            self.motors.actuate(now)
            self.mast_ctrl.receive(now)
            self.mast_ctrl.actuate()
            if dt_s > 0:
                self.rover.step(dt_s)
                self.mast.step(dt_s)
            self._check_ground(now)
            self.now = now
            self.motors.transmit(now)
            self.imu.transmit(now)
            self.mast_ctrl.transmit(now)

    def _check_ground(self, now: float) -> None:
        """Bench fault: a wheel off the world's terrain (the simulator has no ground there)."""
        off = bool(self.rover.wheels_off.any())
        if off:
            self.wheels_off_terrain_steps += 1
        if off and not self._off_before:
            wheels = [n for n, o in zip(("FL", "FR", "RL", "RR"), self.rover.wheels_off, strict=True) if o]
            self.faults_seen.append({"t_s": round(now, 3), "kind": "wheel_off_terrain",
                                     "detail": f"wheels {','.join(wheels)} off the world at "
                                               f"({self.rover.x:.2f}, {self.rover.y:.2f})"})
        self._off_before = off

    # -- the camera -------------------------------------------------------------------------
    def camera_pose(self) -> CameraPose:
        r = self.rover
        origin = np.array([r.x, r.y, r.z])
        return self.mast.camera_pose(origin, r.body_rotation())

    def render_pair(self) -> tuple[np.ndarray, np.ndarray, float]:
        """The stereo pair the true cameras see now (the pose is read under the rig lock)."""
        if self.world is None:
            raise RuntimeError("no world to render (flat terrain only)")
        renderer = self.renderer()
        with self.lock:
            pose, t = self.camera_pose(), self.now
        left, right = renderer.render(pose)
        return left, right, t

    def renderer(self) -> Any:
        """The stereo renderer of the world (built on first use)."""
        if self._renderer is None:
            from hil_sim.render import StereoRenderer

            sigma = self.hw.camera.noise_sigma
            if sigma < 0:
                sigma = float(getattr(self.world, "noise_sigma", 2.0))
            cams = TrueCameras.from_config(self.fsw.camera, self.hw.camera)
            self._renderer = StereoRenderer(self.world, self.fsw.camera, sigma, self.seed, cameras=cams)
        return self._renderer

    # -- reporting --------------------------------------------------------------------------
    def truth(self) -> dict[str, float]:
        r, m = self.rover, self.mast
        pan, tilt, lift = m.true_joints
        return {
            "t_s": self.now,
            "x_m": r.x,
            "y_m": r.y,
            "z_m": r.z,
            "yaw_deg": math.degrees(r.yaw),
            "pitch_deg": math.degrees(r.pitch),
            "roll_deg": math.degrees(r.roll),
            "odometer_m": r.odometer_m,
            "pan_deg": math.degrees(pan),
            "tilt_deg": math.degrees(tilt),
            "lift_m": lift,
            "max_wheel_drop_m": r.max_wheel_drop_m,
        }
