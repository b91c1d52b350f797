"""An Anchorbot's tether winch on the bench: the CAN end of ``WINCH_A`` / ``WINCH_B``.

Frames of ``config/team.dbc`` (:mod:`fsw.comm.team.team_can`), E2E-checked both ways like the
rover's motor controllers (:mod:`hil_sim.hw.motor_controllers`): a command with a bad
checksum, a wrong length or an alive counter out of sequence is counted and ignored.

* ``<W>_CMD``: the tether rate (m/s, paying out positive), Enable, ClearFaults;
* ``<W>_STATUS`` every ``status_period_s``: the paid-out length (the line meter at the
  fairlead, so a tether that slips on the drum still reads true), the load-cell tension,
  Enabled and the fault bits.

The drum follows the command up to ``max_rate_mps``. Latched faults brake the drum
(rate 0) until ClearFaults once the cause is gone:

* FaultTimeout: no command for ``command_timeout_s`` while enabled;
* FaultStall: the drum does not turn although commanded (injected ``winch_fault`` ``stall``)
  for ``stall_detect_s``;
* FaultSlip: the line meter runs away from the drum (injected ``slip``: the tether slips at
  ``slip_rate_mps`` while the fault lasts, braked or not);
* FaultOverTension: the load cell reads over ``trip_n`` (the true tension, or an injected
  ``overtension`` snag that adds ``snag_n``);
* FaultSpool: paying out past the spool's end (the drum stops paying out).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from fsw.comm.e2e import SequenceChecker
from fsw.comm.rover_can import Bad
from fsw.comm.team.team_can import TeamCan, WinchCommand
from fsw.framework.params import param
from hil_sim.faults import FaultInjector


@dataclass(frozen=True)
class WinchConfig:
    status_period_s: float = param(0.1, lo=0.005, hi=10.0, units="s")
    command_timeout_s: float = param(0.5, lo=0.02, hi=60.0, units="s")
    max_rate_mps: float = param(0.25, lo=0.01, hi=3.0, units="m/s", doc="drum rate limit")
    spool_m: float = param(14.0, lo=0.5, hi=100.0, units="m", doc="tether on the spool")
    trip_n: float = param(300.0, lo=1.0, hi=6000.0, units="N", doc="load-cell over-tension trip")
    snag_n: float = param(400.0, lo=0.0, hi=6000.0, units="N", doc="extra load of an injected snag")
    slip_rate_mps: float = param(0.05, lo=0.0, hi=1.0, units="m/s", doc="tether slip of an injected slip")
    stall_detect_s: float = param(0.3, lo=0.01, hi=10.0, units="s")
    e2e_max_delta: int = param(3, lo=1, hi=14)


class WinchNode:
    """One winch: receives its command frames, moves the drum, sends its status frames."""

    def __init__(self, name: str, codec: TeamCan, cfg: WinchConfig, paid_out_m: float,
                 faults: FaultInjector | None = None) -> None:
        self.name, self.codec, self.cfg = name, codec, cfg
        self.faults = faults or FaultInjector()
        self.paid_out_m = float(paid_out_m)  # the true length off the drum (line meter)
        self.rate_cmd = 0.0
        self.enabled = False
        self.latched: set[str] = set()
        self.tension_n = 0.0  # the true tension (the bench's statics set it)
        self.t_cmd = -math.inf
        self.t_status = -math.inf
        self.stalled_s = 0.0
        self.counter = 0
        self.rx_bad = self.rx_seq = self.rx_commands = 0
        self._seq = SequenceChecker(cfg.e2e_max_delta, cfg.command_timeout_s)
        self._cmd_id = codec.frame_id(f"{name}_CMD")

    def on_frame(self, frame_id: int, data: bytes, now: float) -> None:
        if frame_id != self._cmd_id:
            return
        fate, data, _ = self.faults.can_frame(self.name, False, data)
        if fate == "drop":
            return
        d = self.codec.decode(frame_id, data, epoch=None)
        if isinstance(d, Bad) or not isinstance(d, WinchCommand):
            self.rx_bad += 1
            return
        verdict, _ = self._seq.check_frame(self.codec.e2e[frame_id], bytes(data), now)
        if not verdict.accepted:
            self.rx_seq += 1
            return
        self.rx_commands += 1
        self.t_cmd = now
        if d.clear_faults:
            self.latched = {f for f in self.latched if self._cause(f)}
        self.enabled = d.enable
        self.rate_cmd = max(-self.cfg.max_rate_mps, min(self.cfg.max_rate_mps, d.rate_mps))

    def _cause(self, fault: str) -> bool:
        """Whether a latched fault's cause is still there (ClearFaults keeps it then)."""
        mode = self.faults.winch_fault(self.name)
        return {"FaultStall": mode == "stall", "FaultSlip": mode == "slip",
                "FaultOverTension": self.load_n() > self.cfg.trip_n,
                "FaultSpool": self.paid_out_m >= self.cfg.spool_m}.get(fault, False)

    def load_n(self) -> float:
        """What the load cell reads: the true tension, plus a snag's load while one is injected."""
        snag = self.cfg.snag_n if self.faults.winch_fault(self.name) == "overtension" else 0.0
        return self.tension_n + snag

    def step(self, dt: float, now: float) -> None:
        """Move the drum for ``dt`` seconds."""
        mode = self.faults.winch_fault(self.name)
        if self.enabled and now - self.t_cmd > self.cfg.command_timeout_s:
            self.latched.add("FaultTimeout")
        if self.load_n() > self.cfg.trip_n:
            self.latched.add("FaultOverTension")
        rate = self.rate_cmd if self.enabled and not self.latched else 0.0
        if rate > 0 and self.paid_out_m + rate * dt >= self.cfg.spool_m:
            self.latched.add("FaultSpool")
            rate = max(0.0, (self.cfg.spool_m - self.paid_out_m) / dt)  # the drum stops at the spool's end
        if mode == "stall" and rate != 0.0:
            self.stalled_s += dt
            if self.stalled_s >= self.cfg.stall_detect_s:
                self.latched.add("FaultStall")
            rate = 0.0
        else:
            self.stalled_s = 0.0
        self.paid_out_m = max(0.0, self.paid_out_m + rate * dt)
        if mode == "slip":
            self.paid_out_m += self.cfg.slip_rate_mps * dt
            self.latched.add("FaultSlip")

    def poll(self, now: float) -> list[tuple[int, bytes]]:
        """The status frame when one is due (after the fault backdoor), else nothing."""
        if now - self.t_status < self.cfg.status_period_s - 1e-9:
            return []
        self.t_status = now
        self.counter += 1
        running = self.enabled and not self.latched
        fid, data = self.codec.winch_status(self.name, self.paid_out_m, self.load_n(), running,
                                            frozenset(self.latched), self.counter)
        fate, data, _ = self.faults.can_frame(self.name, True, data)
        return [] if fate == "drop" else [(fid, data)]
