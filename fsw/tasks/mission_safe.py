"""The mission's SAFE mode and its recovery: a part of :class:`fsw.tasks.mission.MissionTask`.

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
   good (``SAFE_FINAL``, ``final``, the reason kept in ``reason``); only the operator's
   ``RESUME`` leaves it. A recovery after which a step completed resets the count.

:class:`SafeMode` keeps this state and acts on the mission only through :class:`SafeHost`, the
few things of the sequencer it needs. The try count is not in the checkpoint: a mission
restarted from one begins with a fresh count.
"""

from __future__ import annotations

import math
from typing import Protocol

from fsw.sections import MissionConfig
from fsw.tasks.messages import MOTION_REQUEST, MotionRequest, MotionStatus, MoveOutcome
from fsw.tasks.mission_state import MissionPhase


class SafeHost(Protocol):
    """What SAFE needs of the mission sequencer."""

    @property
    def step(self) -> int: ...

    def event(self, name: str, **args: object) -> None: ...

    def publish(self, topic: str, msg: object) -> None: ...

    def now(self) -> float: ...

    def goto(self, new: MissionPhase) -> None: ...

    def checkpoint(self, phase: MissionPhase) -> None: ...

    def request(self, kind: str) -> None: ...

    def motion_outcome(self) -> MotionStatus | None: ...

    def timed_out(self) -> bool: ...

    def forget_request(self) -> None:
        """Stop waiting for the answer to the last motion request."""

    def continue_mission(self) -> None:
        """Go on where the mission stood (the pending views dropped)."""


class SafeMode:
    """SAFE entries, the automatic recovery and the operator's ``RESUME`` (module docstring)."""

    def __init__(self, cfg: MissionConfig, host: SafeHost) -> None:
        self.cfg = cfg
        self.host = host
        self.entries = 0  # times SAFE was entered
        self.reason: str | None = None  # why the mission is (or last was) in SAFE
        self.since = 0.0  # clock time SAFE was entered (or the last failed try)
        self.tries = 0  # automatic recoveries since the mission last completed a step
        self.final = False  # persistent fault: no more automatic recoveries
        self._recovered_at_step = -1  # the step the last recovery resumed at
        self._clearing = False  # waiting for the motion task to answer clear_faults

    def enter(self, reason: str) -> None:
        """Stop the wheels, park the mast, checkpoint; the reason kept and announced."""
        h = self.host
        if h.step > self._recovered_at_step:  # a step completed since the last recovery
            self.tries = 0
        self.entries += 1
        self.reason = reason
        h.event("SAFE", reason=reason)
        h.goto(MissionPhase.SAFE)
        h.checkpoint(MissionPhase.SAFE)
        self.since = h.now()
        self._clearing = False
        p = self.cfg.park_joints
        h.publish(MOTION_REQUEST, MotionRequest(0, "stop"))
        h.publish(MOTION_REQUEST, MotionRequest(0, "mast", joints=(math.radians(p[0]), math.radians(p[1]), p[2])))
        h.forget_request()

    def run(self) -> None:
        """One activation of the mission in SAFE: wait, clear the faults, or resume."""
        h, cfg = self.host, self.cfg
        now = h.now()
        if self._clearing:
            st = h.motion_outcome()
            if st is None and not h.timed_out():
                return
            self._clearing = False
            if st is None or st.state != MoveOutcome.DONE:
                why = st.reason if st is not None else "no answer from the motion task"
                h.event("RECOVERY_FAILED", reason=f"faults not cleared: {why}")
                self.since = now  # wait again; the try counts
                return
            self._resume()
            return
        if self.final or cfg.safe_recover_s <= 0 or now - self.since < cfg.safe_recover_s:
            return
        if self.tries >= cfg.safe_max_recoveries:
            self.final = True
            self.reason = (f"persistent fault: {self.reason} (SAFE again after "
                           f"{self.tries} automatic recoveries without a completed step)")
            h.event("SAFE_FINAL", reason=self.reason)
            h.checkpoint(MissionPhase.SAFE)
            return
        self.tries += 1
        h.event("RECOVERING", n=self.tries, max=cfg.safe_max_recoveries, reason=self.reason)
        if cfg.safe_clear_faults:
            self._clearing = True
            h.request("clear_faults")
        else:
            self._resume()

    def operator_resume(self) -> None:
        """The operator's ``RESUME`` (the mission is in SAFE): a fresh count, then resume."""
        self.tries = 0  # the operator decided: a fresh count
        self.final = self._clearing = False
        self.host.forget_request()
        self._resume()

    def _resume(self) -> None:
        """Leave SAFE: continue where the mission stood."""
        self._recovered_at_step = self.host.step
        self.host.event("RECOVERED", step=self.host.step, reason=self.reason)
        self.host.continue_mission()
