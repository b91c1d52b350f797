"""What the ground link reads from the executive each activation: a ``VehicleView``.

Telemetry channels (numeric ones, with their limit state, keyed for NAMED_VALUE), the
dictionary CRC, the mission state, health, load/slips/overruns, and the pose and mast: from
the pose estimate on the bus (``[mavlink] pose_topic``, ``fsw.tasks.messages.NavPose``) once
one was heard, else from the configured channels (``deg`` channels converted to radians).
Absent channels give absent messages, never an error (docs/ground.md).
"""

from __future__ import annotations

import math

from fsw.comm.mavlink_adapter import VehicleView
from fsw.comm.mavlink_config import MavlinkConfig
from fsw.comm.mavlink_downlink import ChannelSample, ChannelScheduler, same_value
from fsw.comm.mavlink_telemetry import DICT_CRC_KEY, channel_key, dictionary_crc
from fsw.framework.bus import Mailbox
from fsw.tasks.base import FlightContext

PoseTuple = tuple[float, float, float, float | None, float | None]  # x, y, yaw, pan, tilt


def pose_from_message(msg: object) -> PoseTuple | None:
    """``(x, y, yaw, pan, tilt)`` from a pose message (NavPose or alike); pan/tilt None
    without ``joints``; None for anything that is not a finite pose."""
    try:
        x, y, yaw = (float(getattr(msg, k)) for k in ("x", "y", "yaw"))
        joints = getattr(msg, "joints", None)
        pan, tilt = (float(joints[0]), float(joints[1])) if joints is not None else (None, None)
    except (AttributeError, TypeError, ValueError, IndexError):
        return None
    values: PoseTuple = (x, y, yaw, pan, tilt)
    return values if all(v is None or math.isfinite(v) for v in values) else None


class ViewBuilder:
    """Builds the adapter's input from the task context (one per ground-link task)."""

    def __init__(self, ctx: FlightContext, cfg: MavlinkConfig, pose_box: Mailbox[object],
                 scheduler: ChannelScheduler | None = None) -> None:
        self.ctx, self.cfg, self.pose_box = ctx, cfg, pose_box
        self.scheduler = scheduler  # given: offer only the channels it may send now (the rest it would skip)
        store = ctx.telemetry
        self.keys = {name: channel_key(i, name) for name, i in store.ids.items()}
        self.dict_crc = dictionary_crc((i, name) for name, i in store.ids.items())
        self.fatal_channels = [n for n in store.defs if n.endswith(".tasks_fatal")]
        self.pose: PoseTuple | None = None  # the last good pose message
        # (key, value cell, lo, hi) of every channel, resolved once: build() reads ~190 a frame
        self._chans = [(self.keys[name], cv, store.defs[name].lo, store.defs[name].hi)
                       for name, cv in store.values.items()]

    def build(self, now: float) -> VehicleView:
        store, runtime = self.ctx.telemetry, self.ctx.runtime
        samples = [ChannelSample(DICT_CRC_KEY, self.dict_crc, False)]
        new = tuple.__new__  # ChannelSample(...) without the NamedTuple's Python-level __new__
        sched = self.scheduler
        # the scheduler's own skip rules (ChannelScheduler.due), applied here: a channel sent within
        # the period, or unchanged within the refresh, is skipped with one dict lookup, not ranked
        last = sched.last if sched is not None else {}
        period = sched.period_s - 1e-9 if sched is not None else 0.0
        refresh = sched.refresh_s - 1e-9 if sched is not None else 0.0
        for key, cv, lo, hi in self._chans:  # store.limit_state(name) in ("low", "high"), inlined
            v = cv.value
            if v is None or isinstance(v, str):
                continue
            prev = last.get(key)
            if prev is not None:
                age = now - prev[0]
                if age < period or (age < refresh and same_value(prev[1], v)):
                    continue
            samples.append(new(ChannelSample, (key, v, (lo is not None and v < lo)
                                               or (hi is not None and v > hi))))
        load = int(1000 * runtime.busy_s(self.ctx.frame - 1) / runtime.period_s)
        slips, overruns = runtime.slips, sum(t.overruns for t in runtime.tasks.values())
        x, y, z, roll, pitch, yaw = (self.value(c) for c in self.cfg.pose_channels)
        pan, tilt = (self.value(c) for c in self.cfg.mast_channels)
        msg = self.pose_box.latest()
        if msg is not None:
            self.pose = pose_from_message(msg) or self.pose
        if self.pose is not None:  # the estimate on the bus wins over channels
            x, y, yaw = self.pose[:3]
            if self.pose[3] is not None:
                pan, tilt = self.pose[3:]
        chan = self.cfg.mission_state_channel
        state = store.values[chan].value if chan in store.values else None
        fatal = any((store.get(n) or 0) > 0 for n in self.fatal_channels)
        return VehicleView(
            now, state, fatal, not self.ctx.clock.realtime, load, slips, overruns,
            (x, y, z or 0.0) if x is not None and y is not None else None,
            (roll or 0.0, pitch or 0.0, yaw) if yaw is not None else None,
            (pan, tilt or 0.0) if pan is not None else None, tuple(samples))

    def value(self, name: str) -> float | None:
        """A channel's value in SI units (``deg`` converted), None if absent or not a number."""
        store = self.ctx.telemetry
        if not name or name not in store.values:
            return None
        v = store.values[name].value
        if v is None or isinstance(v, str):
            return None
        try:
            f = float(v)
        except (TypeError, ValueError, OverflowError):
            return None
        if not math.isfinite(f):
            return None
        return math.radians(f) if store.defs[name].units == "deg" else f
