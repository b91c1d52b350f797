"""The ground-link task: MAVLink 2 telemetry, events and map previews down; signed commands up.

Thin (docs/architecture.md, tasks): each activation reads the transport, lets the sans-I/O
adapter (fsw/comm/mavlink_adapter.py) authenticate and decode, records the replay window
(``fsw.comm.mavlink_replay``: at most one write per activation, usually one per
``signing_reserve_s``), then dispatches the accepted commands whose timestamp is on disk
(at most ``commands_per_frame``) through the executive's dictionary and acknowledges them,
answers a stock ground station's polls and PARAM/MISSION requests (``fsw.tasks.mavlink_gcs``),
then sends the adapter's frames for this activation (within ``[mavlink]
budget_bytes_per_frame``) and logs every frame sent and received to the .tlog. Refused
commands are counted and summarised by at most one AUTH_REJECTED event per
``auth_event_period_s``. Operator documentation: docs/ground.md.

Resources (optional, injected by the app or a test): ``mavlink_link`` (a transport; else
the task opens ``[mavlink] url``), ``mavlink_tlog`` (a path or binary stream; else
``tlog_path``), ``unix_time`` (a callable giving Unix seconds for signing and the .tlog; else
the host's ``time.time``).
"""

from __future__ import annotations

import time
from collections.abc import Generator
from pathlib import Path
from typing import BinaryIO, ClassVar

from fsw.comm.mavlink_adapter import MavlinkAdapter
from fsw.comm.mavlink_config import MavlinkConfig
from fsw.comm.mavlink_dialect import mavlink, signing_timestamp
from fsw.comm.mavlink_downlink import TokenBucket, coalesce
from fsw.comm.mavlink_plan import GroundPlan
from fsw.comm.mavlink_replay import TS_PER_S, ReplayJournal
from fsw.comm.mavlink_signing import KeyFileError, Verdict, load_key
from fsw.comm.mavlink_tlog import TlogWriter
from fsw.comm.mavlink_uplink import UplinkBatch
from fsw.drivers import signing_store
from fsw.drivers.mavlink_transport import TransportError, open_transport
from fsw.framework.commands import Arg, CommandDef
from fsw.framework.jobs import JobHandle
from fsw.framework.telemetry import Channel, Event, EventDef, Severity
from fsw.tasks.base import FlightTask
from fsw.tasks.mavlink_dispatch import UplinkDispatch
from fsw.tasks.mavlink_gcs import GcsServices
from fsw.tasks.mavlink_preview import PreviewError, encode_preview, reduce_map
from fsw.tasks.mavlink_view import ViewBuilder

_THROTTLED = ("RX_BAD", "TRANSPORT_FAULT", "TLOG_ERROR", "PREVIEW_BAD", "CMD_BAD_ARGS", "WINDOW_SAVE_ERROR")


class MavlinkTask(FlightTask):
    KIND: ClassVar[str] = "mavlink"
    RATE_HZ: ClassVar[tuple[float, float]] = (2.0, 50.0)  # the 1 Hz HEARTBEAT and its telemetry periods
    DOC: ClassVar[str] = "MAVLink 2 ground link: telemetry, events, map previews; signed commands."
    CHANNELS = (
        Channel("gcs_link", "bool", lo=1, doc="1 while a ground HEARTBEAT was heard within gcs_timeout_s"),
        Channel("tx_bytes", "B", doc="downlink bytes packed since start"),
        Channel("tx_frames", "count"),
        Channel("frame_bytes", "B", doc="downlink bytes of the last activation (<= budget)"),
        Channel("frame_bytes_max", "B", doc="largest activation so far (<= budget)"),
        Channel("tx_errors", "count", hi=0, doc="frames the transport could not send"),
        Channel("deferred", "count", doc="messages postponed by the byte budget"),
        Channel("acks_dropped", "count", hi=0, doc="COMMAND_ACKs of signed commands lost to a flood (queue of 256)"),
        Channel("acks_suppressed", "count", doc="answers to unauthenticated senders not sent (rate limit)"),
        Channel("cmds_busy", "count", doc="signed commands answered TEMPORARILY_REJECTED (commands_per_frame)"),
        Channel("cmds_unrecorded", "count", hi=0, doc="signed commands refused: replay window not saved"),
        Channel("window_writes", "count", doc="replay window writes (one per signing_reserve_s or less)"),
        Channel("polls", "count", doc="ground station polls answered (HOME_POSITION, AUTOPILOT_VERSION, ...)"),
        Channel("polls_unsupported", "count", doc="polls answered UNSUPPORTED"),
        Channel("param_sets", "count", doc="PARAM_SETs applied"),
        Channel("param_refused", "count", doc="signed PARAM_SETs refused (reason in PARAM_SET_REFUSED)"),
        Channel("rx_bytes", "B"),
        Channel("rx_frames", "count"),
        Channel("rx_bad", "count", doc="corrupt uplink frames (CRC, length, prefix)"),
        Channel("cmds_accepted", "count", doc="authenticated commands answered ACCEPTED"),
        Channel("cmds_refused", "count", doc="authenticated commands answered DENIED/FAILED/UNSUPPORTED"),
        Channel("auth_unsigned", "count", hi=0, doc="commands refused: unsigned"),
        Channel("auth_bad_signature", "count", hi=0, doc="commands refused: wrong key or corrupted"),
        Channel("auth_replay", "count", hi=0, doc="commands refused: timestamp not newer (replay)"),
        Channel("auth_stale", "count", hi=0, doc="commands refused: new stream with an old timestamp"),
        Channel("auth_no_key", "count", hi=0, doc="commands refused: no key loaded"),
        Channel("auth_future", "count", hi=0, doc="commands refused: timestamp beyond signing_max_future_s ahead"),
        Channel("events_sent", "count", doc="events sent as STATUSTEXT"),
        Channel("events_dropped", "count", hi=0, doc="events lost to a full downlink queue"),
        Channel("images_sent", "count", doc="map previews completely sent"),
        Channel("preview_codec_bytes", "B", doc="map codec container of the latest preview (its quadtree-reduced "
                                                "map is what the preview shows)"),
        Channel("tlog_records", "count"),
        Channel("budget_bytes", "B", doc="current downlink budget per activation"),
    )
    EVENTS = (
        EventDef("AUTH_REJECTED", Severity.WARNING_HI, "{n} command(s) refused in {span_s:.0f} s ({top}); "
                                                       "latest: {latest}"),
        EventDef("KEY_LOADED", Severity.ACTIVITY_HI, "signing key loaded from {path}; commands must be signed"),
        EventDef("KEY_NONE", Severity.ACTIVITY_HI, "no key_file configured: ground commands are refused"),
        EventDef("KEY_MISSING", Severity.WARNING_HI, "no signing key ({reason}); every command will be refused"),
        EventDef("KEY_PERMISSIONS", Severity.WARNING_LO, "key file {path} is readable by group or others"),
        EventDef("WINDOW_LOADED", Severity.ACTIVITY_LO, "replay window of {n} signed stream(s) restored from {path}"),
        EventDef("WINDOW_BAD", Severity.WARNING_HI, "replay window not restored ({reason}); commands older "
                                                    "than signing_max_age_s are still refused"),
        EventDef("WINDOW_SAVE_ERROR", Severity.WARNING_HI, "replay window not saved to {path}: {error}", throttle=3),
        EventDef("LINK_UP", Severity.ACTIVITY_HI, "ground station {src} heard"),
        EventDef("LINK_LOST", Severity.WARNING_LO, "no ground HEARTBEAT for {timeout_s:.1f} s"),
        EventDef("RX_BAD", Severity.WARNING_LO, "{n} bad uplink frame(s): {reason}", throttle=5),
        EventDef("TRANSPORT_FAULT", Severity.WARNING_HI, "{url}: {fault}", throttle=5),
        EventDef("PARAM_SET", Severity.ACTIVITY_HI, "{text}"),
        EventDef("PARAM_SET_REFUSED", Severity.COMMAND, "{text}"),
        EventDef("CMD_BAD_ARGS", Severity.COMMAND, "{command}: {reason}", throttle=10),
        EventDef("EVENTS_DROPPED", Severity.WARNING_LO, "{n} events were not downlinked (queue full)"),
        EventDef("TLOG_ERROR", Severity.WARNING_HI, "tlog {path}: {error}", throttle=3),
        EventDef("PREVIEW_BAD", Severity.WARNING_LO, "map preview refused: {reason}", throttle=5),
        EventDef("BUDGET_SET", Severity.ACTIVITY_HI, "downlink budget {budget_bytes} B per activation"),
    )
    COMMANDS = (
        CommandDef("SET_BUDGET", (Arg("budget_bytes", int, lo=280, hi=1_000_000, units="B"),),
                   doc="change the downlink byte budget per activation (e.g. for a degraded radio)"),
    )

    # -- start-up ----------------------------------------------------------------------------
    def setup(self) -> None:
        cfg = self.cfg = self.ctx.cfg.mavlink
        res = self.ctx.res
        self._unix = res.unix_time or time.time
        self._epoch_s = float(self._unix()) - self.ctx.clock.now()
        # events so far (other tasks' start-up) and our own until the adapter exists go down first
        self._early: list[Event] | None = list(self.ctx.events.history)
        self.ctx.events.listeners.append(self._on_event)
        key = self._load_key(cfg.key_file)
        self.adapter = MavlinkAdapter(cfg, key, signing_timestamp(self._unix()))
        window_path = (cfg.signing_state_file or str(signing_store.default_path(cfg.key_file))) if key else ""
        self.journal = ReplayJournal(int(cfg.signing_reserve_s * TS_PER_S))
        self.gcs = GcsServices(self.ctx.cfg, self.adapter, self._apply_config)
        self.dispatch = UplinkDispatch(cfg, self.adapter, self.journal, self.gcs, self.ctx.commands, self.event,
                                       window_path, self._unix)
        self.dispatch.restore_window()
        self._plan_box = self.subscribe(cfg.plan_topic, depth=1, policy="drop_oldest")
        for ev in self._early or ():
            self.adapter.push_event(ev)
        self._early = None
        self.link = res.mavlink_link
        self._fault: str | None = None
        if self.link is None:
            try:
                self.link = open_transport(cfg.url, cfg.baud)
            except TransportError as exc:
                self._set_fault(str(exc))
        self.tlog = self._open_tlog(cfg.tlog_path if res.mavlink_tlog is None else res.mavlink_tlog)
        self._preview_box = self.subscribe(cfg.map_preview_topic, depth=1, policy="drop_oldest")
        self._preview: object = None
        self._preview_job: JobHandle | None = None
        self._preview_codec_bytes = 0
        self._views = ViewBuilder(self.ctx, cfg, self.subscribe(cfg.pose_topic, depth=1, policy="drop_oldest"))
        self._gcs_heard_s: float | None = None
        self._link_up = False
        self._dropped_reported = 0
        self._next_decay_s = 1.0
        self._next_flush_s = 0.0

    def _load_key(self, path: str) -> bytes | None:
        if not path:
            self.event("KEY_NONE")
            return None
        try:
            key, private = load_key(path)
        except KeyFileError as exc:
            self.event("KEY_MISSING", reason=str(exc))
            return None
        if not private:
            self.event("KEY_PERMISSIONS", path=path)
        self.event("KEY_LOADED", path=path)
        return key

    def _apply_config(self, new: MavlinkConfig) -> None:
        """A PARAM_SET of a run-time key (fsw.tasks.mavlink_gcs.RUNTIME_KEYS) takes effect now."""
        self.cfg = a = self.adapter.cfg = new
        self.adapter.budget_bytes = new.budget_bytes_per_frame
        for name, period in (("heartbeat", new.heartbeat_period_s), ("sys_status", new.sys_status_period_s),
                             ("pose", new.pose_period_s), ("mast", new.mast_period_s)):
            self.adapter.periodic(name).period_s = period
        self.adapter.channels.period_s, self.adapter.channels.refresh_s = a.channel_period_s, a.channel_refresh_s
        self.adapter.events.bucket.rate_hz, self.adapter.events.bucket.burst = a.statustext_rate_hz, a.statustext_burst
        self.adapter.denials.bucket.rate_hz = a.denial_acks_per_s
        self.adapter.replies.bucket = TokenBucket(a.replies_per_s, int(max(1.0, a.replies_per_s)))
        self.dispatch.cfg = new
        self.dispatch.rejected.period_s = a.auth_event_period_s

    def _open_tlog(self, target: str | BinaryIO) -> TlogWriter | None:
        if not target:
            return None
        if not isinstance(target, str):
            return TlogWriter(target)
        try:
            Path(target).parent.mkdir(parents=True, exist_ok=True)
            stream: BinaryIO = open(target, "ab")  # noqa: SIM115 - lives as long as the task
        except OSError as exc:
            self.event("TLOG_ERROR", path=str(target), error=exc.strerror or str(exc))
            return None
        return TlogWriter(stream)

    def _on_event(self, ev: Event) -> None:
        if self._early is not None:
            self._early.append(ev)
        else:
            self.adapter.push_event(ev)

    # -- one activation --------------------------------------------------------------------------
    def run(self, frame: int) -> None:
        now, unix = self.ctx.clock.now(), float(self._unix())
        stamp = self._epoch_s + now
        chunks = self.link.recv_upto(self.cfg.rx_max_bytes_per_frame, now) if self.link is not None else []
        packetized = self.link is not None and self.link.packetized
        batch = UplinkBatch()
        for chunk in chunks:
            got = self._uplink(chunk, signing_timestamp(unix), packetized, stamp, now)
            batch.commands += got.commands
            batch.requests += got.requests
        if batch.commands or batch.requests:
            self.dispatch.record_window()  # before any accepted command acts: a crash cannot forget it
            plan = self._plan_box.latest()
            if isinstance(plan, GroundPlan):
                self.gcs.plan = plan
            executed = 0
            for cmd in batch.commands:
                executed += self.dispatch.command(cmd, now, executed)
            for req in batch.requests:
                self.dispatch.request(req, now)
        self.dispatch.report_rejections(now)
        if self._link_up and self._gcs_heard_s is not None and now - self._gcs_heard_s > self.cfg.gcs_timeout_s:
            self._link_up = False
            self.event("LINK_LOST", timeout_s=self.cfg.gcs_timeout_s)
        q = self.adapter.events
        if not len(q) and q.dropped > self._dropped_reported:
            self.event("EVENTS_DROPPED", n=q.dropped - self._dropped_reported)
            self._dropped_reported = q.dropped
        self._take_preview(now)
        self.gcs.top_up()
        frames = self.adapter.plan(self._views.build(now), signing_timestamp(unix))
        if self.link is not None:
            for packet in coalesce(frames, self.link.max_send_bytes):
                self.link.send(packet, now)
            self.link.drain_events()  # what went wrong is in fault_reason, reported once per change
            self._set_fault(self.link.fault_reason)
        self._log(stamp, frames)
        if now >= self._next_decay_s:
            self._next_decay_s = now + 1.0
            for name in _THROTTLED:
                self.ctx.events.decay(f"{self.name}.{name}")
        self._publish()

    def _uplink(self, chunk: bytes, now_ts: int, packetized: bool, stamp: float, now: float) -> UplinkBatch:
        batch = self.adapter.receive(chunk, now_ts, packetized)
        self._log(stamp, batch.frames)
        if batch.bad:
            self.event("RX_BAD", n=len(batch.bad), reason=batch.bad[0])
        if batch.heartbeats:
            if not self._link_up:
                self.event("LINK_UP", src="{}/{}".format(*batch.heartbeats[0]))
            self._gcs_heard_s, self._link_up = now, True
        return batch

    def _take_preview(self, now: float) -> None:
        """The latest map update becomes a preview: a slack job reduces it with the map codec
        and JPEG-encodes the decode (``fsw.tasks.mavlink_preview``), at most one job at a time and
        one transfer per ``image_period_s``; the latest map wins."""
        latest = self._preview_box.latest()
        if latest is not None:
            self._preview = latest
        if self._preview is None or self._preview_job is not None or not self.adapter.image_wanted(now):
            return
        obj, self._preview = self._preview, None
        cfg, settings = self.cfg, self.ctx.cfg

        def job() -> Generator[None, None, tuple[bytes, int, int, int]]:
            yield
            source, nbytes = reduce_map(obj, wheel_diameter_m=settings.codec.wheel_m(settings.rover.wheel_diameter_m),
                                       codec=settings.codec)
            yield
            data, w, h = encode_preview(source, cfg.image_max_px, cfg.image_quality)
            return data, w, h, nbytes

        self._preview_job = self.submit_job(job(), "map_preview", on_done=self._preview_done, background=True)

    def _preview_done(self, handle: JobHandle) -> None:
        self._preview_job = None
        if handle.error is not None:
            reason = str(handle.error) if isinstance(handle.error, (PreviewError, ValueError)) else repr(handle.error)
            self.event("PREVIEW_BAD", reason=reason)
            return
        data, w, h, nbytes = handle.result
        self._preview_codec_bytes = nbytes
        self.adapter.offer_image(self.ctx.clock.now(), data, w, h, mavlink.MAVLINK_DATA_STREAM_IMG_JPEG)

    def _log(self, stamp: float, frames: list[bytes]) -> None:
        if self.tlog is None or not frames:
            return
        errors = self.tlog.errors
        for f in frames:
            self.tlog.write(stamp, f)
        if stamp >= self._next_flush_s:  # buffered: one write(2) per second, not per frame
            self._next_flush_s = stamp + 1.0
            self.tlog.flush()
        if self.tlog.errors > errors:
            self.event("TLOG_ERROR", path=str(getattr(self.tlog.stream, "name", "?")),
                       error=self.tlog.last_error or "write failed")

    def _set_fault(self, fault: str | None) -> None:
        if fault and fault != self._fault:
            self.event("TRANSPORT_FAULT", url=self.cfg.url, fault=fault)
        self._fault = fault

    def _publish(self) -> None:
        a, u, v = self.adapter, self.adapter.uplink.counters, self.adapter.verifier.counts
        self.tlm_record({  # one record per frame
            "gcs_link": int(self._link_up),
            "tx_bytes": a.tx_bytes,
            "tx_frames": a.tx_frames,
            "frame_bytes": a.last_frame_bytes,
            "frame_bytes_max": a.max_frame_bytes,
            "tx_errors": self.link.stats.tx_errors if self.link is not None else 0,
            "deferred": a.packer.deferred,
            "acks_dropped": a.acks_dropped,
            "acks_suppressed": a.replies_suppressed,
            "cmds_busy": self.dispatch.counts["busy"],
            "cmds_unrecorded": self.dispatch.counts["unrecorded"],
            "window_writes": self.journal.writes,
            "polls": self.gcs.counts["polls"],
            "polls_unsupported": self.gcs.counts["polls_unsupported"],
            "param_sets": self.gcs.counts["param_sets"],
            "param_refused": self.gcs.counts["param_refused"],
            "rx_bytes": u.bytes,
            "rx_frames": u.frames,
            "rx_bad": u.bad_frames + u.parser_resets,
            "cmds_accepted": self.dispatch.counts["accepted"],
            "cmds_refused": self.dispatch.counts["refused"],
            "auth_unsigned": v[Verdict.UNSIGNED],
            "auth_bad_signature": v[Verdict.BAD_SIGNATURE],
            "auth_replay": v[Verdict.REPLAY],
            "auth_stale": v[Verdict.STALE],
            "auth_no_key": v[Verdict.NO_KEY],
            "auth_future": v[Verdict.FUTURE],
            "events_sent": a.events.sent,
            "events_dropped": a.events.dropped,
            "images_sent": a.images.images_sent,
            "preview_codec_bytes": self._preview_codec_bytes,
            "tlog_records": self.tlog.records if self.tlog is not None else 0,
            "budget_bytes": a.budget_bytes,
        })

    # -- commands ------------------------------------------------------------------------------
    def cmd_SET_BUDGET(self, budget_bytes: int) -> None:
        self.adapter.budget_bytes = budget_bytes
        self.event("BUDGET_SET", budget_bytes=budget_bytes)

    def close(self) -> None:
        """Flush and close the .tlog and the transport (end of a bench run). The .tlog is written
        in one-second batches: a full disk that refuses the last batch is a TLOG_ERROR like any
        other (the records it held are lost, and said so), not a silent end."""
        if self.tlog is not None:
            running, errors = not self.tlog.stopped, self.tlog.errors
            self.tlog.flush()
            self.tlog.close()
            if running and self.tlog.errors > errors:  # (a stopped log said so when it stopped)
                self.event("TLOG_ERROR", path=str(getattr(self.tlog.stream, "name", "?")),
                           error=self.tlog.last_error or "close failed")
            self.tlog = None
        if self.link is not None:
            self.link.close()
            self.link = None
