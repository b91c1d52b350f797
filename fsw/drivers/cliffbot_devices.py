"""The Cliff-bot's device end of the team CAN bus, sans I/O (docs/team.md).

Encodes the winch and wheel commands (alive counters, E2E seal: :mod:`fsw.comm.team.team_can`)
and decodes the winches', wheels' and attitude sensor's status frames: a frame with a bad
checksum, length or reserved bits, or with an alive counter out of sequence, is counted
and ignored, never used and never an exception. :meth:`CliffbotDevices.stale` names a
device whose status has not arrived for ``timeout_s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from fsw.comm.e2e import SequenceChecker
from fsw.comm.rover_can import Bad
from fsw.comm.team.team_can import WINCHES, Attitude, TeamCan, WheelStatus, WinchStatus


@dataclass
class CliffbotDevices:
    codec: TeamCan = field(default_factory=TeamCan)
    timeout_s: float = 0.5
    winch: dict[str, WinchStatus] = field(default_factory=dict)
    attitude: Attitude | None = None
    wheels: WheelStatus | None = None
    seen: dict[str, float] = field(default_factory=dict)
    bad_frames: int = 0
    seq_refused: int = 0
    last_bad: str = ""

    def __post_init__(self) -> None:
        self._seq = SequenceChecker(3, self.timeout_s)
        self._counters: dict[str, int] = {}

    def receive(self, frames: list[tuple[int, bytes]], now: float) -> None:
        for fid, data in frames:
            d = self.codec.decode(fid, data, epoch=None)
            if isinstance(d, Bad):
                self.bad_frames += 1
                self.last_bad = f"{d.reason} {d.detail}".strip()
                continue
            if not self._seq.check_frame(self.codec.e2e[fid], bytes(data), now)[0].accepted:
                self.seq_refused += 1
                continue
            if isinstance(d, WinchStatus):
                self.winch[d.winch] = d
                self.seen[d.winch] = now
            elif isinstance(d, Attitude):
                self.attitude = d
                self.seen["CB_IMU"] = now
            elif isinstance(d, WheelStatus):
                self.wheels = d
                self.seen["CB_WHEELS"] = now

    def stale(self, now: float) -> list[str]:
        return [n for n in (*WINCHES, "CB_IMU", "CB_WHEELS") if now - self.seen.get(n, -math.inf) > self.timeout_s]

    def _next(self, name: str) -> int:
        c = self._counters.get(name, 0) + 1  # the full alive counter (its epoch seals the checksum)
        self._counters[name] = c
        return c

    def commands(self, rates: tuple[float, float], enable: bool, clear: bool,
                 wheels_radps: tuple[float, float]) -> list[tuple[int, bytes]]:
        out = [self.codec.winch_command(w, r, enable, clear, self._next(w))
               for w, r in zip(WINCHES, rates, strict=True)]
        out.append(self.codec.wheel_command(wheels_radps[0], wheels_radps[1], enable, self._next("CB_WHEELS")))
        return out
