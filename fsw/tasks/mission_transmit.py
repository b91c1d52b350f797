"""The mission's TRANSMIT phase: a mixin of :class:`fsw.tasks.mission.MissionTask` (docs/algorithm.md §6).

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
from typing import TYPE_CHECKING

from fsw.framework.bus import Mailbox
from fsw.tasks.base import FlightTask
from fsw.tasks.messages import RADIO_SEND, MapUpdate, RadioSendRequest, RadioStatus
from fsw.tasks.mission_checkpoint import save
from fsw.tasks.mission_state import MissionPhase
from fsw.tasks.sections import MissionConfig

MAP_ID = 1  # the map the mission sends to the Cliff-bot
TX_ASK_S = 2.0  # the send request is repeated this often until the radio reports on it


class MapDelivery(FlightTask):
    """Needs the MissionTask attributes mcfg, latest, radio, radio_box, deadline and its
    _goto, _timed_out and _enter_safe methods."""

    mcfg: MissionConfig
    latest: MapUpdate | None
    radio: RadioStatus | None
    radio_box: Mailbox[RadioStatus]
    deadline: float
    _tx_since = 0.0  # when TRANSMIT began (radio states from before are stale)
    _tx_asked = -math.inf  # when the send request last went out

    if TYPE_CHECKING:  # provided by MissionTask (stubs here would shadow them)
        def _goto(self, new: MissionPhase) -> None: ...

        def _timed_out(self) -> bool: ...

        def _enter_safe(self, reason: str) -> None: ...

    def _begin_transmit(self) -> None:
        self._goto(MissionPhase.TRANSMIT)
        self.deadline = self.ctx.clock.now() + self.mcfg.transmit_timeout_s
        self.radio = None
        self._tx_since = self.ctx.clock.now()
        self._tx_asked = -math.inf

    def _state_transmit(self) -> None:
        for status in self.radio_box.drain():
            if status.map_id == MAP_ID and status.time_s >= self._tx_since:
                self.radio = status
        now = self.ctx.clock.now()
        if self.radio is None and now - self._tx_asked >= TX_ASK_S:
            self._tx_asked = now
            snapshot = self.latest.snapshot if self.latest is not None else None
            self.publish(RADIO_SEND, RadioSendRequest(map_id=MAP_ID, snapshot=snapshot))
        finished = self.radio is not None and self.radio.finished
        if not (finished or self._timed_out()):
            return
        state = self.radio.state.value if finished and self.radio is not None else "timeout"
        self.event("TRANSMITTED", state=state)
        if state == "done":
            self._goto(MissionPhase.DONE)
            save(self, MissionPhase.DONE)
            return
        self.event("UNDELIVERED", state=state)
        self._enter_safe(f"map not delivered ({state})")
