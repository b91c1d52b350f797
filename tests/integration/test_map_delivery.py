"""The Cliff-bot receiver and the executive's radio task (issue 6, items 8 and 9)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from fsw.comm.link import LinkConfig
from fsw.comm.link_sender import LinkSender, SenderState
from fsw.core.codec.mapcodec import encode_map
from fsw.drivers.byte_port import UdpPort
from fsw.drivers.resources import Resources
from fsw.executive.executive import Executive
from fsw.framework.clock import SteppedClock
from fsw.framework.commands import CommandRequest, CommandStatus
from fsw.framework.params import build
from fsw.settings import FswConfig
from fsw.tasks.messages import MAP_UPDATED, MapUpdate
from hil_sim.cliffbot_receiver import Cliffbot
from hil_sim.link.radio_channel import ChannelPort, RadioChannel, RadioChannelConfig


def _map() -> np.ndarray:
    from hil_sim.world.mars import viking_heightfield

    z = viking_heightfield((128, 160), 0.03, 0.14, seed=2)
    z[10:30, 100:150] = np.nan  # never seen
    return z


def test_cliffbot_receives_verifies_decodes_and_draws_figure_13(tmp_path: Path):
    """Issue 6, item 8: received, verified, decoded, reported, PNG beside the original."""
    z = _map()
    enc = encode_map(z, cell_m=0.03, wheel_diameter_m=0.2)
    clock = [0.0]
    ch = RadioChannel(RadioChannelConfig(loss=0.2, ber=1e-5), seed=4)
    bot = Cliffbot(LinkConfig(), ChannelPort(ch, "b", lambda: clock[0]), tmp_path, {7: z})
    tx_port = ChannelPort(ch, "a", lambda: clock[0])
    tx = LinkSender(LinkConfig())
    tx.start(7, enc.data, 0.0)
    while not bot.reports and clock[0] < 120:
        d = tx_port.recv()
        while d is not None:
            tx.receive(d, clock[0])
            d = tx_port.recv()
        for pkt in tx.poll(clock[0]):
            tx_port.send(pkt)
        bot.step(clock[0])
        clock[0] += 0.05
    (rep,) = bot.reports
    assert rep.decoded and rep.map_id == 7 and rep.shape == z.shape
    assert rep.max_error_m is not None and rep.max_error_m <= 0.2
    assert rep.unknown_preserved
    assert Path(rep.png).stat().st_size > 10_000
    assert np.array_equal(np.isnan(np.load(tmp_path / "cliffbot_map_7.npy")), np.isnan(z))


def test_cliffbot_as_a_separate_process_over_udp(tmp_path: Path):
    """Issue 6, items 6 and 8: the Cliff-bot process receives over udp://127.0.0.1."""
    z = _map()
    np.save(tmp_path / "orig.npy", z)
    enc = encode_map(z, cell_m=0.03, wheel_diameter_m=0.2)
    probe = UdpPort("probe", ("127.0.0.1", 0))
    bot_port = probe.address[1]
    probe.close()
    port = UdpPort("udp://127.0.0.1:0", ("127.0.0.1", 0), peer=("127.0.0.1", bot_port))
    host, myport = port.address
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil_sim.cliffbot_receiver", "--listen", f"udp://127.0.0.1:{bot_port}",
         "--peer", f"udp://{host}:{myport}", "--out", str(tmp_path / "cb"), "--original",
         str(tmp_path / "orig.npy"), "--map-id", "3", "--timeout", "60", "--rate-bps", "200000"],
        stdout=subprocess.PIPE, text=True)
    try:
        assert json.loads(proc.stdout.readline())["listening"]
        cfg = LinkConfig(rate_bps=200000, ping_period_s=0.2)
        tx = LinkSender(cfg)
        t0 = time.monotonic()
        tx.start(3, enc.data, 0.0)
        while tx.state is not SenderState.DONE and time.monotonic() - t0 < 30:
            now = time.monotonic() - t0
            d = port.recv(0.005, now)
            while d is not None:
                tx.receive(d, now)
                d = port.recv(0.0, now)
            for pkt in tx.poll(now):
                port.send(pkt, now)
        # the FIN_ACK that ends the Cliff-bot's close (it leaves when the pacer allows)
        while tx.next_deadline_s() is not None and time.monotonic() - t0 < 35:
            for pkt in tx.poll(time.monotonic() - t0):
                port.send(pkt, 0.0)
            time.sleep(0.002)
        assert tx.state is SenderState.DONE
        rep = json.loads(proc.stdout.readline())
        assert proc.wait(timeout=20) == 0
    finally:
        proc.kill()
        port.close()
    assert rep["decoded"] and rep["map_id"] == 3 and rep["max_error_m"] <= 0.2
    assert Path(rep["png"]).exists()


def _exe_cfg() -> FswConfig:
    data = {"executive": {"frame_period_s": 0.1,
                          "groups": [{"name": "fast", "divisor": 1}],
                          "tasks": [{"name": "radio", "kind": "radio", "group": "fast",
                                     "budget_ms": 50.0}]},
            "link": {"transport": "inproc://unused"}}
    return build(FswConfig, data, source="<test>")


def test_radio_task_sends_the_map_within_its_byte_budget():
    """Issue 6, item 9: SEND_MAP encodes in a slack job; frames stay within the byte budget."""
    cfg = _exe_cfg()
    clock = SteppedClock()
    ch = RadioChannel(RadioChannelConfig(loss=0.1), seed=1)
    exe = Executive(cfg, clock, resources=Resources(radio_port=ChannelPort(ch, "a", clock.now)))
    bot = Cliffbot(cfg.link, ChannelPort(ch, "b", clock.now))
    z = _map()
    snap = SimpleNamespace(z=z.astype(np.float64), grid=SimpleNamespace(cell=0.03))
    exe.ctx.bus.publish(MAP_UPDATED, MapUpdate(1, 0.0, 0, 0, 0, 0, 0.0, snap))
    exe.run_lockstep(2)
    resp = exe.ctx.commands.dispatch(CommandRequest("radio.SEND_MAP", {"map_id": 11}))
    assert resp.status is CommandStatus.OK
    frame_bytes = []
    for _ in range(1200):
        exe.run_lockstep(1, before_frame=lambda k: bot.step(clock.now()))
        frame_bytes.append(exe.ctx.telemetry.get("radio.frame_bytes"))
        if exe.ctx.telemetry.get("radio.maps_delivered"):
            break
    assert exe.ctx.telemetry.get("radio.maps_delivered") == 1
    assert bot.reports and bot.reports[0].map_id == 11 and bot.reports[0].decoded
    task = exe.tasks["radio"]
    assert max(frame_bytes) <= task.budget_bytes
    names = [e.name for e in exe.ctx.events.history]
    assert "radio.ENCODED" in names and "radio.DELIVERED" in names
