"""A synthetic mission for the ground-link tests and the docs capture (not a test file).

``DemoMissionTask`` stands in for the mission sequencer, motion and perception tasks until
a bench run exists: it walks through mission states, drives a pose along +x, pans the
mast, grows ``mapped_cells`` and publishes an elevation preview on the configured ``map_preview_topic``.
``build(...)`` makes an executive (SteppedClock) with health, demo and mavlink tasks.
Also the tests' helpers: ``command_frame`` (a COMMAND_LONG from a ground station),
``MemoryLink`` (an in-memory transport), ``write_config`` (a TOML for ``--config``),
``free_udp_port`` and ``RoverThread`` (a lockstep rover paced in a background thread).

Run as a script to leave a .tlog and feed a live ``safer-ground listen``::

    python tests/support/ground_demo.py --url udpin:127.0.0.1:14560 --seconds 60 --tlog /tmp/demo.tlog
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from fsw.drivers.byte_port import BytePort
from fsw.drivers.resources import Resources
from fsw.executive.executive import Executive
from fsw.framework.clock import SteppedClock
from fsw.framework.params import build as build_cfg
from fsw.framework.task import Task
from fsw.framework.telemetry import Channel, EventDef, Severity
from fsw.registry import KINDS
from fsw.settings import FswConfig

STATES = ("INIT", "SELECT", "MOVE", "POINT", "ACQUIRE", "SELECT", "MOVE", "POINT", "ACQUIRE", "TRANSMIT", "DONE")


class DemoMissionTask(Task):
    KIND: ClassVar[str] = "ground_demo"
    CHANNELS = (
        Channel("state", doc="mission state name"),
        Channel("x_m", "m"), Channel("y_m", "m"), Channel("yaw_deg", "deg"),
        Channel("pan_deg", "deg"), Channel("tilt_deg", "deg"),
        Channel("mapped_cells", "cells"),
        Channel("temperature_c", "C", lo=-20.0, hi=40.0, doc="goes out of limits on purpose"),
    )
    EVENTS = (EventDef("STATE", Severity.ACTIVITY_HI, "mission state {state}"),)

    def setup(self) -> None:
        self.k = 0
        self.state = ""

    def run(self, frame: int) -> None:
        t = self.ctx.clock.now()
        state = STATES[min(int(t // 3.0), len(STATES) - 1)]
        if state != self.state:
            self.state = state
            self.event("STATE", state=state)
        self.tlm("state", state)
        self.tlm("x_m", 0.05 * t)
        self.tlm("y_m", 0.1 * math.sin(0.2 * t))
        self.tlm("yaw_deg", 10.0 * math.sin(0.1 * t))
        self.tlm("pan_deg", 60.0 * math.sin(0.3 * t))
        self.tlm("tilt_deg", -30.0)
        self.tlm("mapped_cells", int(400 * t))
        self.tlm("temperature_c", 30.0 + t)
        if frame % 50 == 0:
            self.publish(self.ctx.cfg.mavlink.map_preview_topic, preview(t))


def preview(t: float) -> np.ndarray:
    """A 96 x 128 elevation map: a sloped plateau, a step edge and an unknown far region."""
    yy, xx = np.mgrid[0:96, 0:128]
    z = np.where(yy > 48 + 6 * np.sin(xx / 9.0), 0.0, -0.4) + 0.002 * xx
    z = z.astype(np.float64)
    z[:, int(min(127, 20 + 3 * t)):] = np.nan
    return z


def config(url: str, key_file: str = "", tlog: str = "", budget: int = 600, extra: dict[str, Any] | None = None,
           frame_period_s: float = 0.1) -> FswConfig:
    mav = {"url": url, "key_file": key_file, "tlog_path": tlog, "budget_bytes_per_frame": budget,
           "mission_state_channel": "demo.state",
           "pose_channels": ["demo.x_m", "demo.y_m", "", "", "", "demo.yaw_deg"],
           "mast_channels": ["demo.pan_deg", "demo.tilt_deg"], "image_period_s": 2.0}
    mav.update(extra or {})
    data = {"executive": {"frame_period_s": frame_period_s,
                          "groups": [{"name": "fast", "divisor": 1}, {"name": "slow", "divisor": 10, "offset": 3}],
                          "tasks": [{"name": "demo", "kind": "ground_demo", "group": "fast", "budget_ms": 5.0},
                                    {"name": "mavlink", "kind": "mavlink", "group": "fast", "budget_ms": 10.0},
                                    {"name": "health", "kind": "health", "group": "slow", "budget_ms": 5.0}]},
            "mavlink": mav}
    return build_cfg(FswConfig, data, source="<ground-demo>")


DEMO_KIND = ("ground_demo", "ground_demo:DemoMissionTask")


def register() -> None:
    """Make the demo kind known (tests use monkeypatch instead, so it does not leak)."""
    KINDS.setdefault(*DEMO_KIND)


def build(cfg: FswConfig, resources: Resources | None = None) -> Executive:
    return Executive(cfg, SteppedClock(), resources)


def main() -> int:
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--url", default="udpin:127.0.0.1:14560")
    ap.add_argument("--seconds", type=float, default=30.0, help="real seconds to run (lockstep paced 1:1)")
    ap.add_argument("--tlog", default="")
    ap.add_argument("--key", default="")
    ap.add_argument("--bench", type=int, default=0, metavar="N",
                    help="instead: N lockstep activations on an in-memory link; print the task's time")
    args = ap.parse_args()
    register()
    if args.bench:
        return bench(args.bench, args.key)
    exe = build(config(args.url, args.key, args.tlog))
    t0 = time.monotonic()
    while time.monotonic() - t0 < args.seconds:
        exe.run_lockstep(1)
        time.sleep(max(0.0, t0 + exe.frame * exe.period_s - time.monotonic()))
    exe.tasks["mavlink"].close()  # type: ignore[attr-defined]
    return 0


def command_frame(key: bytes | None, opcode: int, params: tuple[float, ...] = (0.0,) * 6, link_id: int = 1,
                  ts: int | None = None, target: tuple[int, int] = (1, 1), command: int | None = None) -> bytes:
    """A COMMAND_LONG from a ground station (255/190), signed with ``key`` unless None."""
    from fsw.comm.mavlink_dialect import MAV_CMD_DICTIONARY, mavlink, new_codec, signing_timestamp

    mav = new_codec(255, 190)
    if key is not None:
        mav.signing.secret_key, mav.signing.sign_outgoing = key, True
        mav.signing.link_id = link_id
        mav.signing.timestamp = signing_timestamp(time.time()) if ts is None else ts
    msg = mavlink.MAVLink_command_long_message(target[0], target[1], MAV_CMD_DICTIONARY if command is None else command,
                                               0, float(opcode), *params)
    return bytes(msg.pack(mav))


class MemoryLink(BytePort):
    """A ground-link port in memory: the task reads ``inbox`` (datagrams, or one byte stream
    when ``packetized`` is False); the frames it sends are kept per activation in ``sent``."""

    def __init__(self, packetized: bool = True) -> None:
        super().__init__("memory://ground")
        self.packetized = packetized
        self.inbox: list[bytes] = []
        self.sent: list[list[bytes]] = []

    def recv_upto(self, max_bytes: int, now_s: float) -> list[bytes]:
        self.sent.append([])  # a read starts each activation
        if not self.packetized and self.inbox:
            self.inbox = [b"".join(self.inbox)]
        return super().recv_upto(max_bytes, now_s)

    def _recv_internal(self, timeout_s: float, max_bytes: int) -> bytes | None:
        return self.inbox.pop(0) if self.inbox else None

    def _send_internal(self, data: bytes) -> None:
        self.sent[-1].append(data)


def write_config(path: Path, mavlink: dict[str, object], demo: bool = True) -> Path:
    """A flight configuration file (TOML) for the ground tools' ``--config``."""
    tasks = [("demo", "ground_demo", "fast", 5.0)] if demo else [("busy", "busy", "fast", 5.0)]
    tasks += [("mavlink", "mavlink", "fast", 10.0), ("health", "health", "slow", 5.0)]
    lines = ["[executive]", "flight = false", "frame_period_s = 0.1",
             "[[executive.groups]]", 'name = "fast"', "divisor = 1",
             "[[executive.groups]]", 'name = "slow"', "divisor = 10", "offset = 3"]
    for name, kind, group, budget in tasks:
        lines += ["[[executive.tasks]]", f'name = "{name}"', f'kind = "{kind}"', f'group = "{group}"',
                  f"budget_ms = {budget}"]
    lines.append("[mavlink]")
    if demo:
        mavlink = {"mission_state_channel": "demo.state", "pose_channels": ["demo.x_m", "demo.y_m", "", "", "",
                                                                            "demo.yaw_deg"],
                   "mast_channels": ["demo.pan_deg", "demo.tilt_deg"], **mavlink}
    for k, v in mavlink.items():
        lines.append(f"{k} = {v!r}".replace("'", '"') if not isinstance(v, bool) else f"{k} = {str(v).lower()}")
    path.write_text("\n".join(lines) + "\n")
    return path


def free_udp_port() -> int:
    import socket

    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = int(s.getsockname()[1])
    s.close()
    return port


class RoverThread:
    """Runs a lockstep executive paced at ~10x real time in a background thread."""

    def __init__(self, exe: object, step_s: float = 0.01) -> None:
        import threading

        self.exe, self.step_s = exe, step_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        import time

        while not self._stop.is_set():
            self.exe.run_lockstep(1)  # type: ignore[attr-defined]
            time.sleep(self.step_s)

    def __enter__(self) -> RoverThread:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.exe.tasks["mavlink"].close()  # type: ignore[attr-defined]


def bench(n: int, key_file: str) -> int:
    """Execution time of the mavlink task per activation (lockstep, in-memory link, .tlog on)."""
    import tempfile

    from fsw.comm.mavlink_signing import write_key

    with tempfile.TemporaryDirectory() as tmp:
        if not key_file:
            key_file = f"{tmp}/rover.key"
            write_key(key_file)
        link = MemoryLink()
        exe = build(config("udpout:127.0.0.1:9", key_file, f"{tmp}/bench.tlog"), Resources(mavlink_link=link))
        task = exe.tasks["mavlink"]
        ms = []
        for _ in range(n):
            exe.run_lockstep(1)
            ms.append(task.last_s * 1e3)
        arr = np.array(ms[10:])
        sent = sum(len(f) for frames in link.sent for f in frames)
        print(f"mavlink task: {len(arr)} activations, {len(exe.telemetry.defs)} channels, budget 600 B: "
              f"p50 {np.percentile(arr, 50):.3f} ms, p99 {np.percentile(arr, 99):.3f} ms, max {arr.max():.3f} ms; "
              f"downlink {sent / (n * exe.period_s):.0f} B/s")
        task.close()  # type: ignore[attr-defined]
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
