"""The bench's Anchorbot winch: rate tracking, E2E refusals, and each fault latched and braked."""

from __future__ import annotations

import pytest

from fsw.comm.team.team_can import TeamCan, WinchStatus
from hil_sim.faults import FaultInjector
from hil_sim.hw.winch import WinchConfig, WinchNode

DT = 0.05


class Driver:
    """A stepped clock and a command stream for one winch."""

    def __init__(self, faults: FaultInjector | None = None, tension: float = 50.0) -> None:
        self.codec = TeamCan()
        self.faults = faults or FaultInjector()
        self.w = WinchNode("WINCH_A", self.codec, WinchConfig(spool_m=10.0), 5.0, self.faults)
        self.w.tension_n = tension
        self.now = 0.0
        self.counter = 0

    def run(self, seconds: float, rate: float, enable: bool = True, clear: bool = False) -> WinchStatus:
        last = None
        for _ in range(round(seconds / DT)):
            self.now = round(self.now + DT, 9)
            self.faults.update(self.now)
            self.counter += 1
            self.w.on_frame(*self.codec.winch_command("WINCH_A", rate, enable, clear, self.counter), self.now)
            self.w.step(DT, self.now)
            for fid, data in self.w.poll(self.now):
                d = self.codec.decode(fid, data, epoch=None)
                assert isinstance(d, WinchStatus)
                last = d
        assert last is not None
        return last


def test_follows_the_rate_and_reports_length() -> None:
    d = Driver()
    s = d.run(2.0, 0.1)
    assert d.w.paid_out_m == pytest.approx(5.2, abs=1e-6)
    assert s.paid_out_m == pytest.approx(5.2, abs=0.006) and s.enabled and not s.faults
    d.run(1.0, -5.0)  # clipped to the drum's limit
    assert d.w.paid_out_m == pytest.approx(5.2 - 0.25, abs=1e-6)


def test_bad_and_repeated_commands_are_ignored() -> None:
    d = Driver()
    fid, data = d.codec.winch_command("WINCH_A", 0.0, False, False, 1)
    d.w.on_frame(fid, data, 0.0)
    fid, data = d.codec.winch_command("WINCH_A", 0.2, True, False, 2)
    d.w.on_frame(fid, data[:-1] + bytes([data[-1] ^ 1]), 0.01)  # a flipped checksum bit
    d.w.on_frame(fid, data[:5], 0.015)  # a short frame
    assert d.w.rx_bad + d.w.rx_seq == 2 and not d.w.enabled
    d.w.on_frame(fid, data, 0.02)
    d.w.on_frame(fid, data, 0.03)  # the same counter again: a replay
    assert d.w.rx_commands == 2 and d.w.enabled and d.w.rx_seq >= 1


def test_command_timeout_brakes() -> None:
    d = Driver()
    d.run(0.5, 0.1)
    at = d.w.paid_out_m
    for _ in range(20):
        d.now += DT
        d.w.step(DT, d.now)
    assert "FaultTimeout" in d.w.latched and d.w.paid_out_m == pytest.approx(at + 0.1 * 0.5, abs=0.011)


@pytest.mark.parametrize("mode, bit", [("stall", "FaultStall"), ("slip", "FaultSlip"),
                                       ("overtension", "FaultOverTension")])
def test_injected_faults_latch_brake_and_clear_once_gone(mode: str, bit: str) -> None:
    faults = FaultInjector()
    d = Driver(faults)
    d.run(0.5, 0.1)
    faults.inject("winch_fault", start_s=d.now, duration_s=1.0, target="WINCH_A", mode=mode)
    s = d.run(0.6, 0.1)
    assert bit in s.faults and not s.enabled
    if mode == "overtension":
        assert s.tension_n > WinchConfig().trip_n
    held = d.w.paid_out_m
    s = d.run(0.3, 0.1, clear=True)  # the cause is still there: the fault stays
    assert bit in s.faults
    if mode != "slip":
        assert d.w.paid_out_m == pytest.approx(held)  # braked
    else:
        assert d.w.paid_out_m > held  # the tether runs off the drum while it slips
    d.run(0.6, 0.0)  # the fault window ends
    s = d.run(0.2, 0.0, clear=True)
    assert not s.faults
    before = d.w.paid_out_m
    d.run(1.0, 0.1)
    assert d.w.paid_out_m == pytest.approx(before + 0.1, abs=1e-6)


def test_spool_end_stops_paying_out() -> None:
    d = Driver()
    d.w.paid_out_m = 9.95
    s = d.run(1.0, 0.2)
    assert "FaultSpool" in s.faults and d.w.paid_out_m <= 10.0 + 1e-9


def test_fault_row_validation() -> None:
    with pytest.raises(ValueError):
        FaultInjector().inject("winch_fault", target="WINCH_C", mode="stall")
    with pytest.raises(ValueError):
        FaultInjector().inject("winch_fault", target="WINCH_A", mode="driver")
