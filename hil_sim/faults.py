"""The bench's fault-injection backdoor: what goes wrong on the wires and in the devices.

Faults are :class:`FaultSpec` rows, each active from ``start_s`` for ``duration_s`` on the
bench clock. Tests add them with :meth:`FaultInjector.inject`; a scenario or bench config
lists them as ``[[faults]]`` tables (:func:`load_faults`). The hardware models ask the
injector what to do with each frame or byte chunk, so the flight software sees only what a
real bus, line or camera would deliver. Random choices come from one seeded generator, so a
lockstep run with a seed is repeatable.

Kinds:
``can_drop`` (drop frames with probability ``rate``), ``can_delay`` (hold frames ``delay_s``),
``can_corrupt`` (flip bits or truncate, probability ``rate``) -- each on frames to the flight
computer, from it, or both (``direction``) and optionally one axis' frames (``target``);
``bus_off`` (the controllers leave the bus: no rx, no tx; they reboot after);
``motor_fault`` (``target`` axis; ``mode`` ``driver``: driver fault bit, motor coasts;
``stall``: the wheel is blocked and over-current trips); ``serial_noise`` (corrupt a fraction
``rate`` of bytes and insert garbage, both directions); ``serial_disconnect`` (nothing crosses
the line); ``camera_dropout`` (capture requests go unanswered, or with ``mode = "status"`` are
answered DROPOUT); ``mast_stall`` (the mast joints do not move; the controller reports a fault);
``imu_fault`` (the attitude sensor, ``hil_sim.hw.imu``: ``mode`` ``stuck`` repeats its last
frame, ``dropout`` (default) sends nothing, ``selftest`` flags a failed self-test). CAN faults
may target the sensor's frames with ``target = "IMU"``. ``stuck_task`` (the flight task named
by ``target``: ``mode`` ``hang`` (default): its activations do not complete, no work and no
answer to the health pings, so health declares it hung and stops stroking the watchdog;
``overrun``: each activation is charged ``delay_s`` more than it took, so it overruns its
budget and the frame slips; ``hil_sim.bench``); ``radio_outage`` (the Cliff-bot radio link is
dark: every packet on the air in the window is lost, both directions; ``hil_sim.mission.mission_run``
gives the windows to ``hil_sim.link.radio_channel``); ``winch_fault`` (an Anchorbot's tether winch,
``target`` ``WINCH_A`` or ``WINCH_B``, ``hil_sim.hw.winch``: ``mode`` ``stall``: the drum does
not turn; ``slip``: the tether slips off the drum at the winch's slip rate; ``overtension``:
a snag loads the tether past the winch's trip). CAN faults may target a winch's frames too.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fsw.comm.rover_can import AXES
from fsw.framework.params import ConfigError, build, load_toml, param

KINDS = (
    "can_drop",
    "can_delay",
    "can_corrupt",
    "bus_off",
    "motor_fault",
    "serial_noise",
    "serial_disconnect",
    "camera_dropout",
    "mast_stall",
    "imu_fault",
    "stuck_task",
    "radio_outage",
    "winch_fault",
)
TASK_MODES = ("hang", "overrun")
WINCH_TARGETS = ("WINCH_A", "WINCH_B")
CAN_TARGETS = (*AXES, "IMU", *WINCH_TARGETS)


@dataclass(frozen=True)
class FaultSpec:
    """One fault and when it is active."""

    kind: str = param(choices=KINDS, doc="what goes wrong")
    start_s: float = param(0.0, lo=0.0, units="s", doc="bench time it begins")
    duration_s: float = param(1e9, lo=0.0, units="s", doc="how long it lasts (default: for good)")
    rate: float = param(1.0, lo=0.0, hi=1.0, doc="probability per frame (CAN) or per byte (serial)")
    delay_s: float = param(0.0, lo=0.0, hi=60.0, units="s", doc="can_delay: hold time")
    direction: str = param("both", choices=("both", "to_fsw", "from_fsw"), doc="CAN faults: which frames")
    target: str = param("", doc="CAN faults: one axis' frames only; motor_fault: the axis; stuck_task: the task")
    mode: str = param(
        "", choices=("", "driver", "stall", "status", "silent", "stuck", "dropout", "selftest", "slip", "overtension",
                *TASK_MODES),
        doc="motor_fault / camera_dropout / imu_fault / stuck_task / winch_fault variant",
    )

    def __post_init__(self) -> None:
        if self.kind == "stuck_task":
            if not self.target:
                raise ValueError("stuck_task needs a target task name (e.g. target = \"nbv\")")
            if self.mode not in ("", *TASK_MODES):
                raise ValueError(f"stuck_task mode {self.mode!r}: expected {' or '.join(TASK_MODES)}")
            if self.mode == "overrun" and self.delay_s <= 0.0:
                raise ValueError("stuck_task mode overrun needs delay_s > 0 (the extra time of each activation)")
            return
        if self.target and self.target not in CAN_TARGETS:
            raise ValueError(f"target {self.target!r} is not an axis or IMU ({', '.join(CAN_TARGETS)})")
        if self.kind == "motor_fault" and self.target not in AXES:
            raise ValueError("motor_fault needs a target axis")
        if self.kind == "winch_fault" and (self.target not in WINCH_TARGETS
                                           or self.mode not in ("stall", "slip", "overtension")):
            raise ValueError("winch_fault needs target WINCH_A or WINCH_B and mode stall, slip or overtension")

    def active(self, now: float) -> bool:
        return self.start_s <= now < self.start_s + self.duration_s


@dataclass(frozen=True)
class FaultList:
    faults: tuple[FaultSpec, ...] = field(default_factory=tuple)


def load_faults(path: str | Path) -> tuple[FaultSpec, ...]:
    """``[[faults]]`` tables of a TOML file; raises ``ConfigError`` naming the bad key."""
    data = load_toml(path)
    if "faults" not in data:
        raise ConfigError(str(path), "faults", "missing [[faults]] tables")
    return build(FaultList, {"faults": data["faults"]}, source=str(path)).faults


class FaultInjector:
    """Active faults and the seeded dice the hardware models roll against them."""

    def __init__(self, seed: int = 0, faults: tuple[FaultSpec, ...] = ()) -> None:
        self.rng = np.random.default_rng(seed)
        self.faults: list[FaultSpec] = list(faults)
        self.now = 0.0
        self.counts: dict[str, int] = {}
        self.task_names: tuple[str, ...] = ()  # the flight tasks (set by the bench) for stuck_task

    def inject(self, kind: str, start_s: float | None = None, **kw: Any) -> FaultSpec:
        """Add a fault (validated like a config row), starting now unless ``start_s`` is given."""
        row = {"kind": kind, "start_s": self.now if start_s is None else start_s, **kw}
        spec = build(FaultSpec, row, source="<inject>")
        if spec.kind == "stuck_task" and self.task_names and spec.target not in self.task_names:
            raise ValueError(f"stuck_task target {spec.target!r} is not a flight task ({', '.join(self.task_names)})")
        self.faults.append(spec)
        return spec

    def clear(self, kind: str | None = None) -> None:
        self.faults = [f for f in self.faults if kind is not None and f.kind != kind]

    def update(self, now: float) -> None:
        self.now = now

    def active(self, kind: str, now: float | None = None) -> list[FaultSpec]:
        t = self.now if now is None else now
        return [f for f in self.faults if f.kind == kind and f.active(t)]

    def any(self, kind: str) -> bool:
        return bool(self.active(kind))

    def count(self, what: str, n: int = 1) -> None:
        self.counts[what] = self.counts.get(what, 0) + n

    _count = count

    # -- CAN --------------------------------------------------------------------------------
    def can_frame(self, axis: str | None, to_fsw: bool, data: bytes) -> tuple[str, bytes, float]:
        """Fate of one frame: ``("pass"|"drop", data, delay_s)``."""
        delay = 0.0
        for f in self._can_faults(axis, to_fsw):
            if f.kind == "can_drop" and self.rng.random() < f.rate:
                self._count("can_dropped")
                return "drop", data, 0.0
            if f.kind == "can_corrupt" and self.rng.random() < f.rate:
                data = self._corrupt(data)
                self._count("can_corrupted")
            if f.kind == "can_delay":
                delay = max(delay, f.delay_s)
        if delay:
            self._count("can_delayed")
        return "pass", data, delay

    def _can_faults(self, axis: str | None, to_fsw: bool) -> list[FaultSpec]:
        want = "to_fsw" if to_fsw else "from_fsw"
        return [
            f
            for f in self.faults
            if f.kind in ("can_drop", "can_delay", "can_corrupt")
            and f.active(self.now)
            and f.direction in ("both", want)
            and (not f.target or f.target == axis)
        ]

    def _corrupt(self, data: bytes) -> bytes:
        if len(data) > 1 and self.rng.random() < 0.25:
            return data[: int(self.rng.integers(0, len(data)))]  # truncated (wrong DLC)
        b = bytearray(data)
        for _ in range(int(self.rng.integers(1, 4))):
            i = int(self.rng.integers(0, len(b))) if b else 0
            if b:
                b[i] ^= 1 << int(self.rng.integers(0, 8))
        return bytes(b)

    def bus_off(self) -> bool:
        return self.any("bus_off")

    def motor_fault(self, axis: str) -> str:
        """``""`` or the active motor-fault mode (``driver`` / ``stall``) of ``axis``."""
        for f in self.active("motor_fault"):
            if f.target == axis:
                return f.mode or "driver"
        return ""

    # -- serial -----------------------------------------------------------------------------
    def serial_bytes(self, data: bytes) -> bytes:
        """Bytes as they arrive across the line (noise, disconnect)."""
        if not data:
            return data
        if self.any("serial_disconnect"):
            self._count("serial_lost_bytes", len(data))
            return b""
        noise = self.active("serial_noise")
        if not noise:
            return data
        rate = max(f.rate for f in noise)
        arr = np.frombuffer(data, np.uint8).copy()
        hit = self.rng.random(arr.size) < rate
        arr[hit] ^= self.rng.integers(1, 256, int(hit.sum()), dtype=np.uint8)
        out = arr.tobytes()
        self._count("serial_flipped_bytes", int(hit.sum()))
        if self.rng.random() < rate * 10:  # a burst of garbage between frames
            burst = self.rng.integers(0, 256, int(self.rng.integers(1, 16)), dtype=np.uint8).tobytes()
            out = burst + out
            self._count("serial_garbage_bytes", len(burst))
        return out

    # -- camera and mast --------------------------------------------------------------------
    def camera_dropout(self) -> str:
        """``""`` (deliver), ``silent`` (no answer) or ``status`` (answer DROPOUT)."""
        act = self.active("camera_dropout")
        if not act:
            return ""
        return "status" if act[0].mode == "status" else "silent"

    def imu_fault(self) -> str:
        """``""`` or the active attitude-sensor fault mode (``stuck``, ``dropout``, ``selftest``)."""
        act = self.active("imu_fault")
        if not act:
            return ""
        return act[0].mode if act[0].mode in ("stuck", "selftest") else "dropout"

    def winch_fault(self, winch: str) -> str:
        """The active fault mode of an Anchorbot winch ("" when none)."""
        for f in self.active("winch_fault"):
            if f.target == winch:
                return f.mode
        return ""

    def mast_stalled(self) -> bool:
        return self.any("mast_stall")

    # -- flight tasks and the radio ----------------------------------------------------------
    def stuck_task(self, name: str) -> FaultSpec | None:
        """The active ``stuck_task`` fault of the task ``name`` (``mode`` ``hang`` or ``overrun``), or None."""
        for f in self.active("stuck_task"):
            if f.target == name:
                return f
        return None

    def radio_outages(self) -> tuple[tuple[float, float], ...]:
        """``(start_s, duration_s)`` of every ``radio_outage`` fault (the radio channel's windows)."""
        return tuple((f.start_s, f.duration_s) for f in self.faults if f.kind == "radio_outage")
