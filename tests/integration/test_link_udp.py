"""The map link over real loopback UDP: three processes through the relay (issue 12, item 5).

A small map through ``safer-hil relay`` with loss, bit errors, duplication, reordering and a
short outage, between ``safer-hil send-map`` and ``safer-hil cliffbot``: bit-exact, the
sender reports delivered soon after the Cliff-bot verified it, every process exits 0 by
itself. Plus the command lines' bad-input and help behaviour.
"""

from __future__ import annotations

import pytest

from hil_sim.cli import main
from hil_sim.lab.link_udp_experiment import UdpRunSpec, run_udp


@pytest.mark.slow  # seconds of CPU
def test_small_map_over_the_udp_relay_with_an_outage() -> None:
    spec = UdpRunSpec(loss=0.1, seed=2, ber=1e-5, duplicate=0.1, reorder=0.1, reorder_delay_s=0.2,
                      outage=(0.5, 1.0), rate_bps=64000.0, latency_s=0.01, payload_bytes=12000,
                      config=None, timeout_s=40.0, linger_s=1.0, idle_exit_s=1.0)
    row = run_udp(spec)
    assert row["bit_exact"] is True, row
    assert row["sender"] == "done", row
    assert row["exit_codes"] == "0/0/0", row  # rover, Cliff-bot, relay: each stopped by itself
    assert row["delivered_lag_s"] is not None and 0.0 <= row["delivered_lag_s"] <= 10.0, row
    assert row["close"] in ("fin_ack", "linger"), row
    assert row["outage_in_s"] > 0.0, row  # the outage fell inside the transfer
    # each process stopped by itself, none by its own limit (--timeout, --duration 40 s): the rover
    # once delivered, the Cliff-bot once verified (exit 0, not 1), the relay after 1 s without traffic
    assert row["relay_stopped"] == "idle", row


@pytest.mark.parametrize("argv", [
    ["cliffbot", "--count", "0"],
    ["cliffbot", "--listen", "tcp://127.0.0.1:1"],
    ["cliffbot", "--timeout", "nan"],
    ["cliffbot", "--rate-bps", "inf"],
    ["send-map", "--peer", "udp://nohost"],
    ["send-map", "--peer", "udp://127.0.0.1:9", "--bytes", "0"],
    ["send-map", "--peer", "udp://127.0.0.1:9", "--file", "/nonexistent/map.bin"],
    ["send-map", "--peer", "udp://127.0.0.1:9", "--linger-s", "nan"],
    ["relay", "--b-peer", "udp://127.0.0.1:9", "--loss", "1.5"],
    ["relay", "--b-peer", "udp://127.0.0.1:9", "--ber", "nan"],
    ["relay", "--b-peer", "udp://10.0.0.1:9"],
    ["relay", "--b-peer", "udp://127.0.0.1:9", "--outage", "5", "-1"],
    ["experiment", "link", "--transport", "udp", "--losses", "1.2"],
])
def test_bad_input_exits_2_with_one_line(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(argv) == 2
    cap = capsys.readouterr()
    text = (cap.err + cap.out).strip()
    assert "Traceback" not in text and len(text.splitlines()) == 1 and "error" in text


@pytest.mark.parametrize("cmd,word", [("cliffbot", "Cliff-bot"), ("send-map", "RECON-bot"),
                                      ("relay", "127.0.0.1")])
def test_help_explains(cmd: str, word: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        main([cmd, "--help"])
    assert e.value.code == 0
    assert word in capsys.readouterr().out
