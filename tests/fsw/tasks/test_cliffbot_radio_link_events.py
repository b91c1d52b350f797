"""The Cliff-bot's radio task reports its map-link receiver's events (fsw/tasks/cliffbot/radio.py;
docs/link.md): an operator sees a forged OFFER's session dropped and the map verified after it,
on a stepped clock against a RECON-bot link sender over an in-process radio pair."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from task_rig import TaskRig

from fsw.comm import link_packets as lp
from fsw.comm.link_sender import LinkSender
from fsw.drivers.byte_port import InProcPort
from fsw.drivers.resources import Resources
from fsw.framework.schedule import RateGroupConfig, TaskConfig
from fsw.framework.telemetry import Severity
from fsw.settings import FswConfig, load_settings

CLIFFBOT_CONFIG = Path(__file__).resolve().parents[3] / "config" / "cliffbot.toml"


def _config() -> FswConfig:
    """The Cliff-bot's flight configuration with only its radio task scheduled, every frame, and
    no map sync (the map link alone)."""
    cfg = load_settings(CLIFFBOT_CONFIG)
    radio = TaskConfig(name="cb_radio", kind="cliffbot_radio", group="fast", budget_ms=1000.0)
    ex = dataclasses.replace(cfg.executive, groups=(RateGroupConfig(name="fast", divisor=1),), tasks=(radio,))
    return dataclasses.replace(cfg, executive=ex, map_sync=dataclasses.replace(cfg.map_sync, enabled=False))


def test_a_forged_offers_dropped_session_and_the_map_after_it_are_events_of_the_radio_task() -> None:
    cfg = _config()
    recon_port, port = InProcPort.pair("test-cb-radio-link-events")
    rig = TaskRig(cfg, Resources(radio_port=port))
    data = np.random.default_rng(3).integers(0, 256, 6 * cfg.link.segment_bytes, dtype=np.uint8).tobytes()
    tx = LinkSender(cfg.link, session=9)
    tx.start(4, data, 0.0)
    forged = False
    for _ in range(3000):
        now = rig.clock.now()
        for d in tx.poll(now):
            if not forged and lp.packet_type(d) is lp.Ptype.OFFER:
                o = lp.decode(d)
                assert isinstance(o, lp.Offer)
                d = lp.encode(dataclasses.replace(o, segment_bytes=o.segment_bytes // 2))  # a valid CRC-32
                forged = True
            recon_port.send(d, now)
        while (d := recon_port.recv(0.0, now)) is not None:
            tx.receive(d, now)
        rig.run(1)
        if rig.events("cb_radio.MAP_VERIFIED"):
            break
    names = [e.name.split(".", 1)[1] for e in rig.exe.events.history if e.name.startswith("cb_radio.")]
    assert forged and "OFFER_ACCEPTED" in names and "SESSION_DROPPED" in names, names
    assert names.index("SESSION_DROPPED") < names.index("MAP_VERIFIED")
    dropped = rig.events("cb_radio.SESSION_DROPPED")[0]
    assert dropped.text.startswith("map 4: session dropped (") and "do not fit" in dropped.text, dropped.text
    assert dropped.severity is Severity.WARNING_HI
