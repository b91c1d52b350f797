"""``safer-hil serve`` and ``safer-hil bench lockstep`` command lines (issue 3, items 11, bench figure)."""

from __future__ import annotations

import pytest

from fsw.settings import DEFAULT_CONFIG, load_settings
from hil_sim.cli import main
from hil_sim.commands.serve import write_flight_config


@pytest.mark.parametrize(
    "argv",
    [
        ["serve", "--rate-hz", "0"],
        ["serve", "--scenario", "nowhere"],
        ["serve", "--faults", "/nonexistent.toml"],
        ["bench", "lockstep", "--seconds", "-1"],
    ],
)
def test_bad_input_exits_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(argv) == 2
    assert "Traceback" not in capsys.readouterr().err


def test_help_explains(capsys: pytest.CaptureFixture[str]) -> None:
    for argv in (["serve", "--help"], ["bench", "lockstep", "--help"]):
        with pytest.raises(SystemExit) as e:
            main(argv)
        assert e.value.code == 0
    assert "udp_multicast" in capsys.readouterr().out


def test_flight_config_written_for_endpoints(tmp_path) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "f.toml"
    write_flight_config(
        DEFAULT_CONFIG,
        out,
        {
            "can_interface": "udp_multicast",
            "can_channel": "239.74.163.2",
            "serial_url": "socket://127.0.0.1:5000",
            "camera_source": "none",
        },
    )
    d = load_settings(out).devices
    assert (d.can_interface, d.serial_url) == ("udp_multicast", "socket://127.0.0.1:5000")
    assert load_settings(out).executive == load_settings(DEFAULT_CONFIG).executive


def test_bench_lockstep_prints_its_figure(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "lockstep", "--scenario", "lab", "--seconds", "3", "--capture-period", "0"]) == 0
    out = capsys.readouterr().out
    assert "x real time" in out and "CAN" in out
