"""The team in real time (docs/team.md, "Running a team mission", real time): ``safer-hil serve
--scenario cliff-team`` plays both robots' hardware, and the two flight programs run as processes of
their own (``safer-fsw run``, the RECON-bot and the Cliff-bot) on 127.0.0.1. The RECON-bot flies a
one-view mission so its map crosses the radio within the window; the Cliff-bot receives it, plans,
asks for a fix; the RECON-bot views the Anchorbots' plates and answers it (docs/algorithm.md §5.2).
Both radio tasks run the two-way map sync (docs/sync.md). Both send MAVLink heartbeats with their
own system ids, and both exit cleanly on SIGTERM."""

from __future__ import annotations

import json
import os
import select
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hil_helpers import read_until

from fsw.comm.mavlink_dialect import mavlink
from hil_sim.commands.serve import set_keys

BIN = Path(sys.executable).parent
# The RECON-bot starts 2.3 m from the Cliff-bot (from the scenario's start, 4 m off, one marker is
# all it sees of it, and a lone marker that far is refused as ambiguous: docs/team.md)
SCENE = "cliff-team?rover_start.x_m=0.5&rover_start.y_m=0.2"
# The flights' own limit (--duration): the test ends them as soon as the fix is answered (51 s of wall
# on a loaded machine), so a long window costs nothing when they are on time
WINDOW_S = 300.0


def _udp() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.setblocking(False)
    return s


def _heartbeats(sock: socket.socket, parser: mavlink.MAVLink, seen: set[int]) -> None:
    while True:
        try:
            data = sock.recv(65536)
        except BlockingIOError:
            return
        for msg in parser.parse_buffer(data) or []:
            if msg.get_type() == "HEARTBEAT":
                seen.add(int(msg.get_srcSystem()))


def _edit(path: Path, tables: dict[str, dict[str, object]]) -> None:
    text = path.read_text(encoding="utf-8")
    for name, values in tables.items():
        text = set_keys(text, name, values)  # type: ignore[arg-type]
    path.write_text(text, encoding="utf-8")


@pytest.mark.slow
@pytest.mark.timeout(int(WINDOW_S) + 300)  # the window, the bench's start and the exits
def test_serve_and_both_flight_programs_cross_the_map_and_answer_a_fix(tmp_path: Path) -> None:
    recon_cfg, cb_cfg = tmp_path / "recon.toml", tmp_path / "cliffbot.toml"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    serve = subprocess.Popen(
        [str(BIN / "safer-hil"), "serve", "--scenario", SCENE, "--seed", "3", "--can-port", "0",
         "--serial", "pty", "--flight-config", str(recon_cfg), "--cliffbot-config", str(cb_cfg),
         "--duration", str(WINDOW_S + 100), "--report-period", "0", "--camera-timeout", "60"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    gcs = {1: _udp(), 2: _udp()}  # each robot's ground station (heartbeats)
    flights: dict[str, subprocess.Popen[str]] = {}
    out: dict[str, str] = {"recon": "", "cliffbot": ""}
    try:
        read_until(serve, "READY", 180.0)  # returns at READY; the limit only ends a hang
        _edit(recon_cfg, {  # one view, then the map goes to the Cliff-bot: the region of interest
            # counts as mapped after the panorama's one view (no next-view search, no second view)
            "nbv": {"max_steps": 1, "target_mapped_fraction": 0.0},
            "mission": {"panorama_pans_deg": [-90.0], "near_pans_deg": []},
            "mavlink": {"url": f"udpout:127.0.0.1:{gcs[1].getsockname()[1]}"},
            "checkpoint": {"directory": str(tmp_path / "recon_checkpoints")},  # a fresh start, not another run's
        })
        _edit(cb_cfg, {"mavlink": {"url": f"udpout:127.0.0.1:{gcs[2].getsockname()[1]}"},
                       "checkpoint": {"directory": str(tmp_path / "cliffbot_checkpoints")},
                       # the bench's loop stalls while it renders a pair (seconds on a loaded machine): the
                       # team bus's statuses with it
                       "cliffbot_bus": {"status_timeout_s": 30.0},
                       # and the winches time out when the flight program's frames fall behind: SAFE, and
                       # by itself out of it again
                       "cliffbot_mission": {"safe_recover_s": 2.0}})
        for name, cfg in (("recon", recon_cfg), ("cliffbot", cb_cfg)):
            flights[name] = subprocess.Popen(
                [str(BIN / "safer-fsw"), "run", "--config", str(cfg), "--duration", str(WINDOW_S)],
                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        parser = {k: mavlink.MAVLink(None) for k in gcs}
        seen: dict[int, set[int]] = {1: set(), 2: set()}
        deadline = time.monotonic() + WINDOW_S + 30.0
        streams = {p.stdout.fileno(): name for name, p in flights.items() if p.stdout is not None}
        while time.monotonic() < deadline and streams:
            ready, _, _ = select.select(list(streams), [], [], 0.2)
            for fd in ready:
                chunk = os.read(fd, 65536)
                if not chunk:
                    del streams[fd]
                    continue
                out[streams[fd]] += chunk.decode(errors="replace")
            for k, sock in gcs.items():
                _heartbeats(sock, parser[k], seen[k])
            if "fixer.FIX_SENT" in out["recon"] and _answered(out["cliffbot"]):
                break  # the fix crossed: enough
        for p in flights.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        rest = {name: p.communicate(timeout=60) for name, p in flights.items()}
        for name, (so, _) in rest.items():
            out[name] += so
        for k, sock in gcs.items():
            _heartbeats(sock, parser[k], seen[k])
    finally:
        for p in flights.values():
            p.kill()
        serve.send_signal(signal.SIGINT)
        served, _ = serve.communicate(timeout=30)
        for sock in gcs.values():
            sock.close()
    for name, p in flights.items():
        assert p.returncode == 0, f"{name}: {rest[name][1][-2000:]}"
    recon, cb = out["recon"], out["cliffbot"]
    assert seen[1] == {1} and seen[2] == {2}, seen  # both robots' heartbeats, each with its own system id
    said = f"RECON-bot:\n{_events(recon)}\nCliff-bot:\n{_events(cb)}\nbench:\n{served[-1500:]}"
    assert "radio.DELIVERED" in recon, said  # the map crossed the radio ...
    assert "cb_radio.MAP_RECEIVED" in cb, said  # ... and the Cliff-bot took it
    assert "mission.FIX_REQUEST" in cb, said
    assert "fixer.LANDMARKS" in recon and "fixer.FIX_SENT" in recon, said  # through the plates
    assert _answered(cb), said  # fused or refused, the answer arrived
    # Both radio tasks fly the map sync (serve turns it on in the RECON-bot's file): each took the
    # other's tile profile (docs/sync.md, "Tiles")
    assert "radio.SYNC" in recon and "PEER_PROFILE" in recon and "PEER_PROFILE" in cb, said
    truth = json.loads(next(ln for ln in served.splitlines() if ln.startswith("TRUTH "))[6:])
    assert truth["winch_bad"] == 0 and truth["can_bad"] == 0


def _answered(cliffbot_out: str) -> bool:
    """The Cliff-bot's mission took a fix (fused) or refused it: either way the answer arrived."""
    return "mission.FIX: " in cliffbot_out or "mission.FIX_REFUSED: " in cliffbot_out


def _events(out: str) -> str:
    """A flight program's events (its console's lines less the periodic frame lines)."""
    return "\n".join(ln for ln in out.splitlines() if "] frame " not in ln)[-4000:]
