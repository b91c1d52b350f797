"""Several agents' executives stepped on ONE stepped clock (the lockstep bench of a team).

Each executive keeps its own frames, rate groups, bus and telemetry; :class:`Lockstep` only
decides who runs when. A step advances the clock to the earliest frame start due among the
agents and runs, in the order they were added, every agent whose frame starts then (its
``before_frame(k)`` first: the simulator's turn). Agents with the same frame period step in
the same instants; one with another period steps at its own frame starts. With one agent a
step is exactly ``Executive.run_lockstep(1, before_frame)``. Deterministic: no threads, no
wall clock, a fixed order.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from fsw.executive.executive import Executive
from fsw.framework.clock import SteppedClock


@dataclass
class SteppedAgent:
    """One executive of the lockstep and what runs before each of its frames."""

    exe: Executive
    before_frame: Callable[[int], None] | None = None

    def next_start(self) -> float:
        return self.exe.frame_start(self.exe.frame)


class Lockstep:
    """The agents' executives on ``clock`` (module docstring)."""

    def __init__(self, clock: SteppedClock) -> None:
        self.clock = clock
        self.agents: list[SteppedAgent] = []

    def add(self, exe: Executive, before_frame: Callable[[int], None] | None = None,
            align: bool = True) -> SteppedAgent:
        """Step ``exe`` from now on. ``align``: its first frame is the first that starts at or
        after now (an agent joining later); otherwise its frame counter is kept as it is."""
        if exe.clock is not self.clock:
            raise ValueError("an executive of the lockstep must run on the lockstep's clock")
        if align:
            exe.frame = max(exe.frame, math.ceil(self.clock.now() / exe.period_s - 1e-9))
        agent = SteppedAgent(exe, before_frame)
        self.agents.append(agent)
        return agent

    def step(self) -> float:
        """Run the next frame start: every agent due then, in order. Returns that time."""
        if not self.agents:
            raise ValueError("no executive to step")
        t = min(a.next_start() for a in self.agents)
        self.clock.sleep_until(t)
        for a in self.agents:
            if a.next_start() <= t:
                if a.before_frame is not None:
                    a.before_frame(a.exe.frame)
                a.exe.step()
        return t

    def run_frames(self, exe: Executive, frames: int) -> None:
        """Step until ``exe`` (one of the agents) has run ``frames`` more frames."""
        if all(a.exe is not exe for a in self.agents):
            raise ValueError("not an executive of this lockstep")
        target = exe.frame + frames
        while exe.frame < target:
            self.step()
