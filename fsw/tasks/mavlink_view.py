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
from fsw.comm.mavlink_downlink import ChannelTable
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


class _Constant:
    """A channel cell that never changes (the dictionary CRC)."""

    def __init__(self, value: int) -> None:
        self.value = value


class ViewBuilder:
    """Builds the adapter's input from the task context (one per ground-link task)."""

    def __init__(self, ctx: FlightContext, cfg: MavlinkConfig, pose_box: Mailbox[object]) -> None:
        self.ctx, self.cfg, self.pose_box = ctx, cfg, pose_box
        store = ctx.telemetry
        self.keys = {name: channel_key(i, name) for name, i in store.ids.items()}
        self.dict_crc = dictionary_crc((i, name) for name, i in store.ids.items())
        self.fatal_channels = [n for n in store.defs if n.endswith(".tasks_fatal")]
        self.pose: PoseTuple | None = None  # the last good pose message
        # every channel's store cell and limits, resolved once: the scheduler reads them live
        self.channels = ChannelTable(((DICT_CRC_KEY, _Constant(self.dict_crc), None, None),) + tuple(
            (self.keys[name], cv, store.defs[name].lo, store.defs[name].hi) for name, cv in store.values.items()))

    def build(self, now: float) -> VehicleView:
        store, runtime = self.ctx.telemetry, self.ctx.runtime
        keys, changed = self.keys, self.channels.changed
        for name in store.changed:  # what was written with a new value since the last build
            changed[keys[name]] = None
        store.changed.clear()
        load = int(1000 * runtime.busy_s(self.ctx.frame - 1) / runtime.period_s)
        slips, overruns = runtime.slips, sum(t.overruns for t in runtime.tasks.values())
        msg = self.pose_box.latest()
        if msg is not None:
            self.pose = pose_from_message(msg) or self.pose
        pose, chans = self.pose, self.cfg.pose_channels
        z, roll, pitch = (self.value(chans[i]) for i in (2, 3, 4))
        # the estimate on the bus wins over channels (read only when there is none)
        x, y, yaw = pose[:3] if pose is not None else (self.value(chans[i]) for i in (0, 1, 5))
        pan, tilt = pose[3:] if pose is not None and pose[3] is not None else (
            self.value(c) for c in self.cfg.mast_channels)
        chan = self.cfg.mission_state_channel
        state = store.values[chan].value if chan in store.values else None
        fatal = any((store.get(n) or 0) > 0 for n in self.fatal_channels)
        return VehicleView(
            now, state, fatal, not self.ctx.clock.realtime, load, slips, overruns,
            (x, y, z or 0.0) if x is not None and y is not None else None,
            (roll or 0.0, pitch or 0.0, yaw) if yaw is not None else None,
            (pan, tilt or 0.0) if pan is not None else None, self.channels)

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
