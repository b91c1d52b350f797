"""``safer-hil serve`` and ``safer-hil bench lockstep`` command lines (issue 3, items 11, bench figure)."""

from __future__ import annotations

from pathlib import Path

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
        ["serve", "--scenario", "flat", "--can-port", "70000"],
        ["serve", "--scenario", "flat", "--can-bind", "192.0.2.254"],  # not an address of this machine
        ["serve", "--scenario", "flat", "--can-multicast", "nonexistent0"],
        ["bench", "lockstep", "--seconds", "-1"],
        ["experiment", "team", "--scenes", "0"],
        ["experiment", "team", "--scenes", "1", "--scenario", "lab"],  # a scenario with no team
        ["experiment", "sync", "--seeds", "0"],
        ["experiment", "sync", "--cases", "outage,nope"],
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
    out = capsys.readouterr().out
    assert "--can-bind" in out and "127.0.0.1" in out and "udp_multicast" in out


def test_flight_config_written_for_endpoints(tmp_path) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "f.toml"
    write_flight_config(
        DEFAULT_CONFIG,
        out,
        {
            "can_interface": "udp_hub",
            "can_channel": "127.0.0.1:43113",
            "serial_url": "socket://127.0.0.1:5000",
            "camera_source": "none",
        },
    )
    d = load_settings(out).devices
    assert (d.can_interface, d.can_channel, d.serial_url) == ("udp_hub", "127.0.0.1:43113", "socket://127.0.0.1:5000")
    assert load_settings(out).executive == load_settings(DEFAULT_CONFIG).executive


@pytest.mark.parametrize(("keys", "reason"), [
    ({"can_interface": "udp_multicast", "can_channel": "239.74.163.2"}, "can_multicast_interface"),
    ({"can_interface": "udp_hub", "can_channel": "127.0.0.1:port"}, "HOST:PORT"),
])
def test_flight_config_refuses_a_bus_that_could_leave_unasked(tmp_path, keys, reason) -> None:  # type: ignore[no-untyped-def]
    """Issue 31: udp_multicast only on a named interface; a udp_hub channel is HOST:PORT."""
    from fsw.framework.params import ConfigError

    out = tmp_path / "f.toml"
    write_flight_config(DEFAULT_CONFIG, out, keys)
    with pytest.raises(ConfigError, match=reason):
        load_settings(out)


def test_bench_lockstep_prints_its_figure(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "lockstep", "--scenario", "lab", "--seconds", "3", "--capture-period", "0"]) == 0
    out = capsys.readouterr().out
    assert "x real time" in out and "CAN" in out


def test_serve_link_options_go_into_the_flight_config(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 29, item 5: serve takes the MAVLink link, key, tlog and checkpoint folder; without
    --flight-config they are a usage error (exit 2, one line)."""
    import argparse

    from hil_sim.commands.serve import link_keys

    ns = argparse.Namespace(mavlink_url="udpin:127.0.0.1:14560", key_file=str(tmp_path / "k"),
                            tlog=str(tmp_path / "f.tlog"), checkpoint_dir=str(tmp_path / "ck"))
    out = tmp_path / "f.toml"
    write_flight_config(DEFAULT_CONFIG, out, {"camera_source": "none"}, link_keys(ns))
    cfg = load_settings(out)
    assert (cfg.mavlink.url, cfg.mavlink.key_file, cfg.mavlink.tlog_path) == (ns.mavlink_url, ns.key_file, ns.tlog)
    assert cfg.checkpoint.directory == ns.checkpoint_dir
    assert cfg.mavlink.budget_bytes_per_frame == load_settings(DEFAULT_CONFIG).mavlink.budget_bytes_per_frame
    assert main(["serve", "--tlog", "x.tlog", "--duration", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--flight-config" in err[0]


def test_bench_planner_times_the_flight_footprints_against_whole_map_filters(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "planner", "--repeat", "1"]) == 0
    out = capsys.readouterr().out
    assert "ground_layers (flight)" in out and "footprint_known by whole-map filters" in out
    assert "same cells: yes" in out
    assert main(["bench", "planner", "--repeat", "0"]) == 2
    assert main(["bench", "planner", "--scenario", "lab"]) == 2  # no team there
    assert "no team" in capsys.readouterr().out


def test_a_named_command_imports_its_module_alone() -> None:
    """``safer-hil run ...`` parses its options without importing the other command modules (the
    lab's tables and pandas among them): each start of a mission, a bench or a one-line refusal
    is that much shorter. The whole tool's help still lists every command."""
    import subprocess
    import sys

    probe = ("import sys\nfrom hil_sim import cli\nassert cli.main(['run', '--steps', '-1']) == 2\n"
             "print(sorted(m for m in sys.modules if m.startswith(('hil_sim.commands.', 'hil_sim.lab.experiments',\n"
             "                                                     'hil_sim.lab.bench', 'pandas'))))")
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip() == "['hil_sim.commands.run']"
    from hil_sim import cli

    assert cli.named_command(["bench", "cycle", "--help"]) == ("bench", "cycle")
    assert cli.named_command(["bench", "--help"]) is None and cli.named_command([]) is None
    listed = cli.build_parser().format_help()
    assert all(name in listed for group, name in cli.COMMANDS if not group)
