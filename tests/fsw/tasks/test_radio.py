"""The radio task (fsw/tasks/radio_task.py) on a stepped clock against a Cliff-bot link
receiver over an in-process radio pair (issue 11, item 5)."""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
from task_rig import TaskRig, task_config

from fsw.comm.link_receiver import LinkReceiver
from fsw.core.codec.mapcodec import decode_map
from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap
from fsw.drivers.byte_port import InProcPort
from fsw.drivers.resources import Resources
from fsw.tasks.messages import MAP_UPDATED, RADIO_SEND, MapUpdate, RadioSendRequest

CFG = task_config(("radio", "radio"))
GRID = MapGrid(0.0, 0.0, 0.05, 64, 48)
_names = itertools.count()


class CliffBot:
    """The receiving end, run between the rover's frames."""

    def __init__(self) -> None:
        name = f"test-radio-{next(_names)}"
        self.rover_port, self.port = InProcPort.pair(name)
        self.rx = LinkReceiver(CFG.link)
        self.maps: list[tuple[int, bytes]] = []

    def __call__(self, rig: TaskRig) -> None:
        now = rig.clock.now()
        while (d := self.port.recv(0.0, now)) is not None:
            self.rx.receive(d, now)
        for pkt in self.rx.poll(now):
            self.port.send(pkt, now)
        while (got := self.rx.take_map()) is not None:
            self.maps.append(got)


def _rig() -> tuple[TaskRig, CliffBot]:
    cb = CliffBot()
    return TaskRig(CFG, Resources(radio_port=cb.rover_port)), cb


def _map() -> ElevationMap:
    emap = ElevationMap(GRID)
    xs, ys = GRID.centers()
    known = xs < 2.5
    emap.z[known] = (0.05 * np.sin(3 * xs) + 0.02 * ys)[known]
    emap.var[known], emap.n[known] = 1e-4, 1
    return emap


def _run(rig: TaskRig, cb: CliffBot, frames: int) -> list[int]:
    """Frames with the Cliff-bot answering; the bytes the task sent in each."""
    sent = []
    for _ in range(frames):
        rig.exe.run_lockstep(1)
        sent.append(int(rig.tlm("radio.frame_bytes") or 0))
        cb(rig)
    return sent


def test_the_latest_map_is_encoded_sent_within_budget_and_delivered() -> None:
    rig, cb = _rig()
    emap = _map()
    rig.publish(MAP_UPDATED, MapUpdate(3, 0.0, int(emap.mapped.sum()), 0, 0, 0, 0.0, emap))
    rig.publish(RADIO_SEND, RadioSendRequest(map_id=7))
    sent = []
    for _ in range(60):
        sent += _run(rig, cb, 10)
        if cb.maps:
            break
    assert [m for m, _ in cb.maps] == [7]
    budget = rig.task("radio").budget_bytes
    assert max(sent) <= budget and sum(sent) >= len(cb.maps[0][1])
    dec = decode_map(cb.maps[0][1])
    got: Any = np.asarray(dec.z)
    assert got.shape == GRID.shape
    known = np.isfinite(emap.z)
    assert np.array_equal(np.isfinite(got), known)
    assert np.abs(got[known] - emap.z[known]).max() <= CFG.codec.error_bound_wheels * CFG.rover.wheel_diameter_m
    assert len(rig.events("radio.ENCODED")) == 1 and len(rig.events("radio.DELIVERED")) == 1
    _run(rig, cb, 5)
    assert rig.tlm("radio.maps_delivered") == 1 and rig.tlm("radio.state") == "done"


def test_no_map_yet_is_an_event() -> None:
    rig, cb = _rig()
    assert rig.command("radio.SEND_MAP", map_id=1).status.name == "OK"
    _run(rig, cb, 3)
    assert len(rig.events("radio.NO_MAP")) == 1 and not rig.events("radio.ENCODED") and not cb.maps


def test_a_second_map_during_a_transfer_is_refused_busy() -> None:
    rig, cb = _rig()
    emap = _map()
    rig.publish(MAP_UPDATED, MapUpdate(1, 0.0, 1, 0, 0, 0, 0.0, emap))
    rig.publish(RADIO_SEND, RadioSendRequest(map_id=1))
    _run(rig, cb, 1)
    rig.publish(RADIO_SEND, RadioSendRequest(map_id=2))
    _run(rig, cb, 1)
    assert [e.text for e in rig.events("radio.BUSY")] == ["map 2 refused: map 1 still in transfer"]
