"""The MAVLink adapter: the executive's telemetry, events and commands <-> MAVLink 2 frames.

Sans-I/O (as in h11): the task hands it uplink bytes, the time and a view of the
executive; it returns authenticated commands and the downlink frames of this activation,
never more than ``budget_bytes_per_frame`` bytes. Downlink priorities, highest first:

1. HEARTBEAT (1 Hz);  2. STATUSTEXT of FATAL/WARNING events;
3. SYS_STATUS, LOCAL_POSITION_NED + ATTITUDE (rover), GIMBAL_DEVICE_ATTITUDE_STATUS (mast);
4. COMMAND_ACK of authenticated commands;  5. answers to unauthenticated senders (denials,
   polls, PARAM/MISSION replies), rate-limited when queued;  6. a PARAM_VALUE list in progress
   (at most half the budget);  7. other STATUSTEXT;  8. NAMED_VALUE_FLOAT/INT channels;
9. map preview image packets.

Whatever does not fit waits for the next activation at the same priority. An unauthenticated
sender cannot fill a queue or push the heartbeat out: its answers pass a token bucket before
they are queued (beyond it they are counted, not sent), and they rank below telemetry.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

from fsw.comm import mavlink_telemetry as tm
from fsw.comm.mavlink_commands import Reason
from fsw.comm.mavlink_config import MavlinkConfig
from fsw.comm.mavlink_dialect import mavlink, new_codec
from fsw.comm.mavlink_downlink import (
    ChannelSample,
    ChannelScheduler,
    ChannelTable,
    DownlinkQueue,
    Packer,
    Periodic,
    TokenBucket,
)
from fsw.comm.mavlink_image import ImageSender
from fsw.comm.mavlink_signing import SignatureVerifier, Verdict
from fsw.comm.mavlink_uplink import CommandIn, Uplink, UplinkBatch
from fsw.core.geometry import wrap_angle
from fsw.framework.telemetry import Event, Severity

_UINT16_MAX = 65535


@dataclass(frozen=True)
class VehicleView:
    """What the task read from the executive for this activation's downlink."""

    time_s: float
    mission_state: Any = None
    fatal: bool = False
    simulated: bool = False
    load_dpercent: int = 0
    slips: int = 0
    overruns: int = 0
    position: tuple[float, float, float] | None = None  # world x, y, z (m)
    rpy: tuple[float, float, float] | None = None  # roll, pitch, yaw (rad, z-up world)
    mast: tuple[float, float] | None = None  # pan, tilt (rad)
    channels: tuple[ChannelSample, ...] | ChannelTable = ()  # a table is read live, lazily


@dataclass
class ReplyQueue:
    """Answers to senders that need no key: a token bucket decides at enqueue time, so a flood
    costs a counter, never memory or downlink time."""

    bucket: TokenBucket
    depth: int
    items: deque[mavlink.MAVLink_message] = field(default_factory=deque)
    suppressed: int = 0

    def push(self, now_s: float, msgs: list[mavlink.MAVLink_message]) -> bool:
        self.bucket.refill(now_s)
        if len(self.items) + len(msgs) > self.depth or not self.bucket.take():
            self.suppressed += 1
            return False
        self.items.extend(msgs)
        return True


class MavlinkAdapter:
    """One ground link's protocol state: codec, signing, queues, schedules and counters."""

    def __init__(self, cfg: MavlinkConfig, key: bytes | None, signing_ts: int) -> None:
        self.cfg = cfg
        self.budget_bytes = cfg.budget_bytes_per_frame  # settable by command (SET_BUDGET)
        self.codec = new_codec(cfg.system_id, cfg.component_id)
        if key is not None and cfg.sign_downlink:
            self.codec.signing.secret_key = key
            self.codec.signing.sign_outgoing = True
            self.codec.signing.link_id = cfg.link_id
            self.codec.signing.timestamp = signing_ts
        self.verifier = SignatureVerifier(key, cfg.signing_max_age_s, max_future_s=cfg.signing_max_future_s)
        self.uplink = Uplink(self.verifier, cfg.system_id, cfg.component_id)
        self.packer = Packer(self.codec)
        self.events = DownlinkQueue(cfg.statustext_queue, Severity[cfg.statustext_min_severity],
                                 TokenBucket(cfg.statustext_rate_hz, cfg.statustext_burst))
        self.channels = ChannelScheduler(cfg.channel_period_s, cfg.channel_refresh_s)
        self.images = ImageSender()
        # authenticated commands: bounded (a signed sender is trusted, yet a flood loses ACKs, counted)
        self._acks: deque[mavlink.MAVLink_command_ack_message] = deque(maxlen=256)
        self.acks_dropped = 0
        # unauthenticated senders: denials coalesced to a trickle; answers to polls and requests
        self.denials = ReplyQueue(TokenBucket(cfg.denial_acks_per_s, 5), 8)
        self.replies = ReplyQueue(TokenBucket(cfg.replies_per_s, int(max(1.0, cfg.replies_per_s))), 64)
        self.param_stream: deque[mavlink.MAVLink_message] = deque()  # a PARAM_REQUEST_LIST answer
        self._due = {"heartbeat": Periodic(cfg.heartbeat_period_s), "sys_status": Periodic(cfg.sys_status_period_s),
                     "pose": Periodic(cfg.pose_period_s), "mast": Periodic(cfg.mast_period_s)}
        self._next_image_s = 0.0
        self._chunk_id = 0
        self._text: deque[mavlink.MAVLink_statustext_message] = deque()  # chunks of the event being sent
        self._last_pose: tuple[float, VehicleView] | None = None
        self.tx_frames = 0
        self.tx_bytes = 0
        self.last_frame_bytes = 0
        self.max_frame_bytes = 0

    # -- uplink -----------------------------------------------------------------------------
    def receive(self, data: bytes, now_ts: int, packet_end: bool = False) -> UplinkBatch:
        batch = self.uplink.feed(data, now_ts, packet_end)
        self._clock_signing(now_ts)
        return batch

    def restore_window(self, streams: dict[tuple[int, int, int], int], now_ts: int) -> None:
        """A saved replay window (after a restart); our own signing time moves past it too."""
        self.verifier.restore(streams)
        self.verifier.changed = False
        self._clock_signing(now_ts)

    def _clock_signing(self, now_ts: int) -> None:
        """Our signing time follows the clock (a ground station refuses a new stream more than a
        minute old) and never falls behind a timestamp the ground has used."""
        if self.codec.signing.sign_outgoing:
            self.codec.signing.timestamp = max(self.codec.signing.timestamp, now_ts,
                                               self.verifier.newest_timestamp() + 1)

    def ack(self, cmd: CommandIn, result: int, reason: Reason, opcode: int, now_s: float = 0.0) -> bool:
        """Queue the COMMAND_ACK of ``cmd``: an authenticated command's in the ACK queue, any
        other through the rate limit (False: suppressed, counted)."""
        msg = mavlink.MAVLink_command_ack_message(cmd.command_id, result, int(reason), opcode,
                                                  cmd.src_system, cmd.src_component)
        if cmd.verdict is not Verdict.OK:
            return (self.denials if result == mavlink.MAV_RESULT_DENIED else self.replies).push(now_s, [msg])
        if len(self._acks) == self._acks.maxlen:
            self.acks_dropped += 1
        self._acks.append(msg)
        return True

    def reply(self, now_s: float, msgs: list[mavlink.MAVLink_message]) -> bool:
        """Answers to a request that needs no key (rate-limited; False: suppressed, counted)."""
        return self.replies.push(now_s, msgs)

    @property
    def replies_suppressed(self) -> int:
        return self.denials.suppressed + self.replies.suppressed

    def periodic(self, name: str) -> Periodic:
        """The schedule of ``heartbeat``, ``sys_status``, ``pose`` or ``mast`` (a PARAM_SET changes it)."""
        return self._due[name]

    # -- inputs for the downlink ----------------------------------------------------------------
    def push_event(self, ev: Event) -> None:
        self.events.push(ev)

    def image_wanted(self, now_s: float) -> bool:
        """True when a new map preview would be accepted now (encode it only then)."""
        return not self.images.busy and now_s >= self._next_image_s

    def offer_image(self, now_s: float, data: bytes, width: int, height: int, kind: int) -> None:
        self.images.offer(data, width, height, kind, self.cfg.image_quality)
        self._next_image_s = now_s + self.cfg.image_period_s

    # -- downlink -------------------------------------------------------------------------------
    def plan(self, v: VehicleView, now_ts: int = 0) -> list[bytes]:
        """The frames of this activation, in priority order, within the byte budget;
        ``now_ts`` is the signing time (10 us units since 2015) of this activation."""
        self._clock_signing(now_ts)
        p, now, ms = self.packer, v.time_s, int(v.time_s * 1000) & 0xFFFFFFFF
        p.begin(self.budget_bytes)
        if self._due["heartbeat"].due(now) and p.offer([tm.heartbeat(v.mission_state, v.fatal, v.simulated)]):
            self._due["heartbeat"].done(now)
        self.events.bucket.refill(now)
        self._events(Severity.WARNING_LO)
        if self._due["sys_status"].due(now) and p.offer([self._sys_status(v)]):
            self._due["sys_status"].done(now)
        if self._due["pose"].due(now) and (v.position is not None or v.rpy is not None) \
                and p.offer(self._pose(ms, now, v)):
            self._due["pose"].done(now)
            self._remember_pose(now, v)
        if self._due["mast"].due(now) and v.mast is not None and p.offer([tm.mast_attitude(ms, *v.mast)]):
            self._due["mast"].done(now)
        for q in (self._acks, self.replies.items, self.denials.items):
            while q and p.offer([q[0]]):
                q.popleft()
        half = p.used + p.remaining // 2
        while self.param_stream and p.used < half and p.offer([self.param_stream[0]]):
            self.param_stream.popleft()
        self._events(Severity.DIAGNOSTIC)
        chans = v.channels
        ranked = self.channels.ranked(now, chans) if isinstance(chans, ChannelTable) else self.channels.due(now, chans)
        for s in ranked:
            msg = tm.named_value(ms, s.key, s.value)
            if msg is None:
                continue
            if not p.offer([msg]):
                break
            self.channels.mark(now, s)
        while (msg := self.images.peek()) is not None and p.offer([msg]):
            self.images.consume()
        self.tx_frames += len(p.frames)
        self.tx_bytes += p.used
        self.last_frame_bytes = p.used
        self.max_frame_bytes = max(self.max_frame_bytes, p.used)
        return p.frames

    def _events(self, worst_allowed: Severity) -> None:
        """STATUSTEXT for queued events up to ``worst_allowed``; the chunks of a long text may
        span activations, so no event is too long for the smallest budget."""
        while True:
            while self._text and self.packer.offer([self._text[0]]):
                self._text.popleft()
            if self._text:
                return
            ev = self.events.head()
            if ev is None or ev.severity > worst_allowed or not self.events.bucket.take():
                return
            self._chunk_id = self._chunk_id % _UINT16_MAX + 1
            self._text.extend(tm.statustext(ev.severity, f"{ev.name}: {ev.text}", self._chunk_id))
            self.events.pop()

    def _sys_status(self, v: VehicleView) -> mavlink.MAVLink_sys_status_message:
        u = self.uplink.counters
        total = u.frames + u.bad_frames
        drop_cpct = int(10000 * u.bad_frames / total) if total else 0

        def c16(n: int) -> int:
            return max(0, min(_UINT16_MAX, int(n)))

        # no sensor claimed present; health all ones = nothing unhealthy (an all-zero health word
        # reads as failed sensors, e.g. "fence breach" in MAVProxy)
        return mavlink.MAVLink_sys_status_message(
            0, 0, 0xFFFFFFFF, c16(min(v.load_dpercent, 1000)), _UINT16_MAX, -1, -1, c16(drop_cpct), c16(u.bad_frames),
            c16(v.slips), c16(v.overruns), c16(self.uplink.rejected()), c16(self.events.dropped), 0, 0, 0)

    def _pose(self, ms: int, now: float, v: VehicleView) -> list[mavlink.MAVLink_message]:
        """LOCAL_POSITION_NED and ATTITUDE; velocities and rates by difference of samples."""
        vel, rates = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
        if self._last_pose is not None and now > self._last_pose[0]:
            dt, prev = now - self._last_pose[0], self._last_pose[1]
            if v.position is not None and prev.position is not None:
                a, b = v.position, prev.position
                vel = ((a[0] - b[0]) / dt, (a[1] - b[1]) / dt, (a[2] - b[2]) / dt)
            if v.rpy is not None and prev.rpy is not None:
                a, b = v.rpy, prev.rpy
                rates = (wrap_angle(a[0] - b[0]) / dt, wrap_angle(a[1] - b[1]) / dt, wrap_angle(a[2] - b[2]) / dt)
        out: list[mavlink.MAVLink_message] = []
        if v.position is not None:
            out.append(tm.local_position_ned(ms, v.position, vel))
        if v.rpy is not None:
            out.append(tm.attitude(ms, v.rpy, rates))
        return out

    def _remember_pose(self, now: float, v: VehicleView) -> None:
        self._last_pose = (now, v)
