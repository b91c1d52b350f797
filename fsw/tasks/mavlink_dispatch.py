"""The ground-link task's uplink side: the replay window on disk, and what each command gets.

A part of ``fsw.tasks.mavlink_task.MavlinkTask`` (split by meaning: this object decides, the
task moves bytes); it acts on the task only through :class:`EventSink`, the task's ``event``.
Per activation the task calls :meth:`UplinkDispatch.record_window` once, before any command
acts, then :meth:`UplinkDispatch.command` / :meth:`UplinkDispatch.request` per message:

* a COMMAND_LONG other than the dictionary's is a ground station's poll (``fsw.tasks.mavlink_gcs``);
* a dictionary command runs only when signed (``Verdict.OK``), its timestamp is on disk
  (``fsw.comm.mavlink_replay``; else DENIED ``UNRECORDED``) and fewer than ``commands_per_frame``
  ran in this activation (else TEMPORARILY_REJECTED ``BUSY``);
* every refusal is counted and summarised: one AUTH_REJECTED per ``auth_event_period_s``
  (``fsw.framework.summary``), naming the latest (its opcode, or its MAV_CMD for a PARAM_SET).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol

from fsw.comm.mavlink_adapter import MavlinkAdapter
from fsw.comm.mavlink_commands import RESULT_OF_STATUS, Reason, decode_args
from fsw.comm.mavlink_config import MavlinkConfig
from fsw.comm.mavlink_dialect import MAV_CMD_DICTIONARY, mavlink, signing_timestamp
from fsw.comm.mavlink_replay import ReplayJournal
from fsw.comm.mavlink_signing import Verdict
from fsw.comm.mavlink_uplink import CommandIn, GcsRequest
from fsw.drivers import signing_store
from fsw.framework.commands import CommandDispatcher, CommandRequest, CommandStatus
from fsw.framework.summary import Summary
from fsw.tasks.mavlink_gcs import GcsServices

_REASON_OF_VERDICT = {Verdict.UNSIGNED: Reason.UNSIGNED, Verdict.BAD_SIGNATURE: Reason.BAD_SIGNATURE,
                      Verdict.REPLAY: Reason.REPLAY, Verdict.STALE: Reason.STALE, Verdict.NO_KEY: Reason.NO_KEY,
                      Verdict.FUTURE: Reason.FUTURE}



class EventSink(Protocol):
    """The task's ``event``: emits ``<task>.<name>`` with its arguments."""

    def __call__(self, name: str, **args: object) -> None: ...


class UplinkDispatch:
    """The replay window on disk, the command and request verdicts, and their counters."""

    def __init__(self, cfg: MavlinkConfig, adapter: MavlinkAdapter, journal: ReplayJournal, gcs: GcsServices,
                 commands: CommandDispatcher, event: EventSink, window_path: str,
                 unix: Callable[[], float]) -> None:
        self.cfg = cfg  # replaced by the task when a PARAM_SET changes it
        self.adapter = adapter
        self.journal = journal
        self.gcs = gcs
        self.commands = commands
        self.event = event
        self.window_path = window_path  # "" without a key: nothing to keep
        self._unix = unix
        self.rejected = Summary(cfg.auth_event_period_s)
        self.counts = {"accepted": 0, "refused": 0, "busy": 0, "unrecorded": 0}
        self.seq = 0  # dictionary commands dispatched

    def restore_window(self) -> None:
        if not self.window_path:
            return
        streams, problem = signing_store.load(self.window_path)
        if problem is not None:
            self.event("WINDOW_BAD", reason=problem)
        elif streams:
            self.event("WINDOW_LOADED", n=len(streams), path=self.window_path)
        self.adapter.restore_window(streams, signing_timestamp(self._unix()))
        self.journal.restore(streams)

    def record_window(self) -> None:
        """Put every accepted timestamp on disk before any command acts: one write at most,
        and none while the marks already on disk cover them (fsw.comm.mavlink_replay)."""
        v = self.adapter.verifier
        if not (self.window_path and v.changed):
            return
        window = self.journal.plan(v.streams)
        if window is not None:
            try:
                signing_store.save(self.window_path, window)
            except OSError as exc:  # the commands not covered are refused; retried on the next one
                self.event("WINDOW_SAVE_ERROR", path=self.window_path, error=exc.strerror or str(exc))
                return
            self.journal.written(window)
        v.changed = False

    def _refuse(self, now: float, what: str, src: str, why: str) -> None:
        self.rejected.note(now, why, f"{what} from {src}: {why}")

    def report_rejections(self, now: float) -> None:
        r = self.rejected.report(now)
        if r is not None:
            self.event("AUTH_REJECTED", n=r.count, span_s=r.span_s, top=r.top(), latest=r.latest)

    def command(self, cmd: CommandIn, now: float, executed: int) -> int:
        """Answer one COMMAND_LONG; returns 1 if a dictionary command was dispatched."""
        if cmd.command_id != MAV_CMD_DICTIONARY:  # a ground station's poll: answered, never evented
            self.gcs.poll(cmd, now)
            return 0
        p1 = cmd.param1
        opcode = int(p1) if math.isfinite(p1) and p1.is_integer() and 0 <= p1 < 2**24 else 0
        src = f"{cmd.src_system}/{cmd.src_component}"
        what = f"opcode 0x{opcode:x}" if opcode or p1 == 0 else f"opcode {p1!r}"
        if cmd.verdict is not Verdict.OK:
            self._refuse(now, what, src, cmd.verdict.value)
            self.adapter.ack(cmd, mavlink.MAV_RESULT_DENIED, _REASON_OF_VERDICT[cmd.verdict], opcode, now)
            return 0
        if not self.journal.covers(cmd.stream, cmd.timestamp):  # its freshness is not on disk: never run
            self.counts["unrecorded"] += 1
            self._refuse(now, what, src, "UNRECORDED")
            self.adapter.ack(cmd, mavlink.MAV_RESULT_DENIED, Reason.UNRECORDED, opcode, now)
            return 0
        if executed >= self.cfg.commands_per_frame:
            self.counts["busy"] += 1
            self._refuse(now, what, src, "BUSY")
            self.adapter.ack(cmd, mavlink.MAV_RESULT_TEMPORARILY_REJECTED, Reason.BUSY, opcode, now)
            return 0
        self.seq += 1
        self._dictionary(cmd, opcode, src)
        return 1

    def _dictionary(self, cmd: CommandIn, opcode: int, src: str) -> None:
        p1 = cmd.param1
        commands = self.commands
        name = commands.name_of(opcode) if opcode else None
        if name is None:  # let the dispatcher refuse it, so counters and events stay uniform
            commands.dispatch(CommandRequest(f"opcode {p1!r}", {}, self.seq, f"mavlink:{src}"))
            self.counts["refused"] += 1
            self.adapter.ack(cmd, mavlink.MAV_RESULT_DENIED, Reason.UNKNOWN_OPCODE, opcode)
            return
        try:
            args = decode_args(commands.definitions()[name][1], cmd.params)
        except ValueError as exc:
            self.event("CMD_BAD_ARGS", command=name, reason=str(exc))
            self.counts["refused"] += 1
            self.adapter.ack(cmd, mavlink.MAV_RESULT_DENIED, Reason.BAD_ARGUMENTS, opcode)
            return
        resp = commands.dispatch(CommandRequest(name, args, self.seq, f"mavlink:{src}"))
        ok = resp.status is CommandStatus.OK
        self.counts["accepted" if ok else "refused"] += 1
        reason = Reason.VALIDATION if resp.status is CommandStatus.VALIDATION_ERROR else Reason.NONE
        self.adapter.ack(cmd, RESULT_OF_STATUS[resp.status], reason, opcode)

    def request(self, req: GcsRequest, now: float) -> None:
        src = f"{req.src_system}/{req.src_component}"
        if req.verdict is not None and req.verdict is not Verdict.OK:
            self._refuse(now, "PARAM_SET", src, req.verdict.value)
        recorded = req.verdict is Verdict.OK and self.journal.covers(req.stream, req.timestamp)
        text = self.gcs.request(req, now, recorded)
        if text is not None:
            self.event("PARAM_SET_REFUSED" if "refused" in text else "PARAM_SET", text=text)
