"""The bench's recorder tap: reads a flight executive's bus and event log after each frame and
logs a vehicle source of a Foxglove MCAP recording (``ground.recording``).

The flight tasks do not know it exists: it only adds mailboxes on the bus and a listener on the
event log, drained by :meth:`BusTap.poll` outside the tasks' activations."""

from __future__ import annotations

from typing import Any

from fsw.framework.telemetry import Event
from fsw.tasks.messages import CAMERA_FRAME, MAP_UPDATED, NAV_POSE, NBV_RESULT
from ground.recording import VehicleSource


class BusTap:
    """Feed ``source`` from executive ``exe``; poses at most every ``pose_period_s`` of mission time."""

    def __init__(self, exe: Any, source: VehicleSource, pose_period_s: float = 0.2) -> None:
        bus, name = exe.bus, f"recorder.{source.vehicle}"
        self.exe, self.source, self.pose_period_s = exe, source, pose_period_s
        self.maps = bus.subscribe(MAP_UPDATED, name, depth=4)
        self.poses = bus.subscribe(NAV_POSE, name, depth=1)
        self.frames = bus.subscribe(CAMERA_FRAME, name, depth=4)
        self.views = bus.subscribe(NBV_RESULT, name, depth=4)
        self.plans = bus.subscribe(exe.ctx.cfg.mavlink.plan_topic, name, depth=4)
        self._events: list[Event] = []
        exe.events.listeners.append(self._events.append)
        self._next_pose_s = 0.0

    def poll(self) -> None:
        now = float(self.exe.ctx.clock.now())
        src = self.source
        for up in self.maps.drain():
            src.map(up.time_s, up.snapshot)
        nav = self.poses.latest()
        if nav is not None and now >= self._next_pose_s:
            self._next_pose_s = now + self.pose_period_s
            src.pose(now, nav)
        for fr in self.frames.drain():
            src.images(fr.time_s, fr.left, fr.right)
        for view in self.views.drain():
            if view is not None:
                x, y, yaw = view.rover
                src.chosen_view(now, x, y, yaw, f"{view.method} {view.expected_new_cells:.0f} cells")
        for plan in self.plans.drain():
            src.plan_update(now, plan.stations, plan.fence, plan.current)
        events, self._events[:] = list(self._events), []
        for ev in events:
            src.event(ev)

    def close(self) -> None:
        if self._events.append in self.exe.events.listeners:
            self.exe.events.listeners.remove(self._events.append)
