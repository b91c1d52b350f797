"""The mission's TRANSMIT phase: a part of :class:`fsw.tasks.mission.MissionTask` (docs/algorithm.md §6).

Delivery is a fact, not a hope: the send request, carrying the map itself (so a mission
resumed at its last step needs no ``map.updated``), goes out from the phase's first frame
(never from ``setup``, where a resumed mission begins TRANSMIT before the radio task listens)
and is repeated every ``TX_ASK_S`` until the radio reports on the map. The mission is DONE
only on the Cliff-bot's whole-map acknowledgement (radio DONE); a link that failed or was
rejected, or no delivery within ``[mission] transmit_timeout_s``, is the event UNDELIVERED and
SAFE with the reason ``map not delivered (STATE)``; leaving SAFE transmits again.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Protocol

from fsw.sections import MissionConfig
from fsw.tasks.messages import RADIO_SEND, MapUpdate, RadioSendRequest, RadioStatus
from fsw.tasks.mission_state import MissionPhase

MAP_ID = 1  # the map the mission sends to the Cliff-bot
TX_ASK_S = 2.0  # the send request is repeated this often until the radio reports on it


class DeliveryHost(Protocol):
    """What the map delivery needs of the mission sequencer."""

    @property
    def latest(self) -> MapUpdate | None: ...

    def now(self) -> float: ...

    def event(self, name: str, **args: object) -> None: ...

    def publish(self, topic: str, msg: object) -> None: ...

    def goto(self, new: MissionPhase) -> None: ...

    def checkpoint(self, phase: MissionPhase) -> None: ...

    def timed_out(self) -> bool: ...

    def set_deadline(self, t: float) -> None: ...

    def enter_safe(self, reason: str) -> None: ...


class MapDelivery:
    """The TRANSMIT phase (module docstring); acts on the mission through :class:`DeliveryHost`."""

    def __init__(self, cfg: MissionConfig, host: DeliveryHost) -> None:
        self.cfg = cfg
        self.host = host
        self.radio: RadioStatus | None = None  # the radio's last report on the map
        self._tx_since = 0.0  # when TRANSMIT began (radio states from before are stale)
        self._tx_asked = -math.inf  # when the send request last went out

    def begin(self) -> None:
        h = self.host
        h.goto(MissionPhase.TRANSMIT)
        h.set_deadline(h.now() + self.cfg.transmit_timeout_s)
        self.radio = None
        self._tx_since = h.now()
        self._tx_asked = -math.inf

    def run(self, statuses: Iterable[RadioStatus]) -> None:
        h = self.host
        for status in statuses:
            if status.map_id == MAP_ID and status.time_s >= self._tx_since:
                self.radio = status
        now = h.now()
        if self.radio is None and now - self._tx_asked >= TX_ASK_S:
            self._tx_asked = now
            latest = h.latest
            snapshot = latest.snapshot if latest is not None else None
            h.publish(RADIO_SEND, RadioSendRequest(map_id=MAP_ID, snapshot=snapshot))
        finished = self.radio is not None and self.radio.finished
        if not (finished or h.timed_out()):
            return
        state = self.radio.state.value if finished and self.radio is not None else "timeout"
        h.event("TRANSMITTED", state=state)
        if state == "done":
            h.goto(MissionPhase.DONE)
            h.checkpoint(MissionPhase.DONE)
            return
        h.event("UNDELIVERED", state=state)
        h.enter_safe(f"map not delivered ({state})")
