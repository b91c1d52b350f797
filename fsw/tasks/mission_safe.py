"""The mission's SAFE mode and its recovery: a mixin of :class:`fsw.tasks.mission.MissionTask`.

Entering SAFE stops the wheels, parks the mast, raises ``SAFE`` and checkpoints. The mission
then waits for the operator's ``RESUME``, or with ``[mission] safe_recover_s`` > 0 recovers by
itself after that long in SAFE, as an operator would:

1. it clears what the sequencer is allowed to clear: the latched motor-controller and mast
   faults (a ``clear_faults`` request to the motion task, the ``motion.CLEAR_FAULTS`` of the
   ground; ``[mission] safe_clear_faults``). An engaged emergency stop is never released by
   the sequencer: the motion task refuses, and the try counts as failed;
2. it resumes where the mission stood (``RECOVERED``). A fault that has ended (a bus-off, a
   camera dropout, a motor fault that went away) no longer stops the mission; it enters SAFE
   again only on a new fault or a fault that is still there;
3. a fault that is still there brings SAFE back before the mission completes another step.
   After ``[mission] safe_max_recoveries`` such tries in a row the mission stays in SAFE for
   good (``SAFE_FINAL``, ``safe_final``, the reason kept in ``safe_reason``); only the
   operator's ``RESUME`` leaves it. A recovery after which a step completed resets the count.

The try count is not in the checkpoint: a mission restarted from one begins with a fresh count.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from fsw.core.planning.view_candidates import CandidateView
from fsw.framework.commands import CommandError
from fsw.tasks.base import FlightTask
from fsw.tasks.messages import MOTION_REQUEST, MapUpdate, MotionRequest, MotionStatus, MoveOutcome
from fsw.tasks.mission_checkpoint import save
from fsw.tasks.mission_state import MissionPhase
from fsw.tasks.sections import MissionConfig


class SafeRecovery(FlightTask):
    """Needs the MissionTask attributes: mcfg, state, step, pending, latest, waiting_for,
    safe_entries, safe_reason, _safe_since; and its _goto, _request, _motion_outcome,
    _timed_out and _next_view methods."""

    mcfg: MissionConfig
    state: MissionPhase
    step: int
    latest: MapUpdate | None
    pending: list[CandidateView]
    waiting_for: int | None
    safe_entries: int
    safe_reason: str | None
    _safe_since: float

    if TYPE_CHECKING:  # provided by MissionTask (stubs here would shadow them)
        def _goto(self, new: MissionPhase) -> None: ...

        def _request(
            self,
            kind: str,
            target: tuple[float, float, float] | None = None,
            joints: tuple[float, float, float] | None = None,
        ) -> None: ...

        def _motion_outcome(self) -> MotionStatus | None: ...

        def _timed_out(self) -> bool: ...

        def _next_view(self) -> None: ...

    # Recovery state (class defaults: set before setup() and by a checkpoint resume alike).
    recover_tries = 0  # automatic recoveries since the mission last completed a step
    safe_final = False  # persistent fault: no more automatic recoveries
    _recovered_at_step = -1  # the step the last recovery resumed at
    _clearing = False  # waiting for the motion task to answer clear_faults

    def _enter_safe(self, reason: str) -> None:
        if self.step > self._recovered_at_step:  # a step completed since the last recovery
            self.recover_tries = 0
        self.safe_entries += 1
        self.safe_reason = reason
        self.event("SAFE", reason=reason)
        self._goto(MissionPhase.SAFE)
        save(self, MissionPhase.SAFE)
        self._safe_since = self.ctx.clock.now()
        self._clearing = False
        p = self.mcfg.park_joints
        self.publish(MOTION_REQUEST, MotionRequest(0, "stop"))
        self.publish(MOTION_REQUEST, MotionRequest(0, "mast", joints=(math.radians(p[0]), math.radians(p[1]), p[2])))
        self.waiting_for = None

    def _state_safe(self) -> None:
        now = self.ctx.clock.now()
        if self._clearing:
            st = self._motion_outcome()
            if st is None and not self._timed_out():
                return
            self._clearing = False
            if st is None or st.state != MoveOutcome.DONE:
                why = st.reason if st is not None else "no answer from the motion task"
                self.event("RECOVERY_FAILED", reason=f"faults not cleared: {why}")
                self._safe_since = now  # wait again; the try counts
                return
            self._resume()
            return
        if self.safe_final or self.mcfg.safe_recover_s <= 0 or now - self._safe_since < self.mcfg.safe_recover_s:
            return
        if self.recover_tries >= self.mcfg.safe_max_recoveries:
            self.safe_final = True
            self.safe_reason = (f"persistent fault: {self.safe_reason} (SAFE again after "
                                f"{self.recover_tries} automatic recoveries without a completed step)")
            self.event("SAFE_FINAL", reason=self.safe_reason)
            save(self, MissionPhase.SAFE)
            return
        self.recover_tries += 1
        self.event("RECOVERING", n=self.recover_tries, max=self.mcfg.safe_max_recoveries, reason=self.safe_reason)
        if self.mcfg.safe_clear_faults:
            self._clearing = True
            self._request(kind="clear_faults")
        else:
            self._resume()

    def _resume(self) -> None:
        """Leave SAFE: continue where the mission stood (or from the panorama if nothing is mapped)."""
        self._recovered_at_step = self.step
        self.event("RECOVERED", step=self.step, reason=self.safe_reason)
        self.pending.clear()
        if self.latest is None:  # nothing mapped yet: start again with the panorama
            self._goto(MissionPhase.INIT)
            return
        self._goto(MissionPhase.SELECT)
        self._next_view()

    def cmd_RESUME(self) -> None:
        if self.state != MissionPhase.SAFE:
            raise CommandError("not in SAFE")
        self.recover_tries = 0  # the operator decided: a fresh count
        self.safe_final = self._clearing = False
        self.waiting_for = None
        self._resume()
