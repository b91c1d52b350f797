"""The ground-link task's uplink side: the replay window on disk, and what each command gets.

A mixin of ``fsw.tasks.mavlink_task.MavlinkTask`` (split by meaning: this half decides, the
task moves bytes). Per activation the task calls :meth:`UplinkDispatch._record_window` once,
before any command acts, then :meth:`UplinkDispatch._command` / :meth:`UplinkDispatch._request`
per message:

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

from fsw.comm.mavlink_adapter import MavlinkAdapter
from fsw.comm.mavlink_commands import RESULT_OF_STATUS, Reason, decode_args
from fsw.comm.mavlink_config import MavlinkConfig
from fsw.comm.mavlink_dialect import MAV_CMD_DICTIONARY, mavlink, signing_timestamp
from fsw.comm.mavlink_replay import ReplayJournal
from fsw.comm.mavlink_signing import Verdict
from fsw.comm.mavlink_uplink import CommandIn, GcsRequest
from fsw.drivers import signing_store
from fsw.framework.commands import CommandRequest, CommandStatus
from fsw.framework.summary import Summary
from fsw.tasks.base import FlightTask
from fsw.tasks.mavlink_gcs import GcsServices

_REASON_OF_VERDICT = {Verdict.UNSIGNED: Reason.UNSIGNED, Verdict.BAD_SIGNATURE: Reason.BAD_SIGNATURE,
                      Verdict.REPLAY: Reason.REPLAY, Verdict.STALE: Reason.STALE, Verdict.NO_KEY: Reason.NO_KEY,
                      Verdict.FUTURE: Reason.FUTURE}

class UplinkDispatch(FlightTask):
    """Needs the MavlinkTask attributes below (set in its ``setup``)."""

    cfg: MavlinkConfig
    adapter: MavlinkAdapter
    journal: ReplayJournal
    gcs: GcsServices
    _window_path: str
    _rejected: Summary
    _cmd_counts: dict[str, int]
    _seq: int
    _unix: Callable[[], float]

    def _restore_window(self) -> None:
        if not self._window_path:
            return
        streams, problem = signing_store.load(self._window_path)
        if problem is not None:
            self.event("WINDOW_BAD", reason=problem)
        elif streams:
            self.event("WINDOW_LOADED", n=len(streams), path=self._window_path)
        self.adapter.restore_window(streams, signing_timestamp(self._unix()))
        self.journal.restore(streams)

    def _record_window(self) -> None:
        """Put every accepted timestamp on disk before any command acts: one write at most,
        and none while the marks already on disk cover them (fsw.comm.mavlink_replay)."""
        v = self.adapter.verifier
        if not (self._window_path and v.changed):
            return
        window = self.journal.plan(v.streams)
        if window is not None:
            try:
                signing_store.save(self._window_path, window)
            except OSError as exc:  # the commands not covered are refused; retried on the next one
                self.event("WINDOW_SAVE_ERROR", path=self._window_path, error=exc.strerror or str(exc))
                return
            self.journal.written(window)
        v.changed = False

    def _refuse(self, now: float, what: str, src: str, why: str) -> None:
        self._rejected.note(now, why, f"{what} from {src}: {why}")

    def _report_rejections(self, now: float) -> None:
        r = self._rejected.report(now)
        if r is not None:
            self.event("AUTH_REJECTED", n=r.count, span_s=r.span_s, top=r.top(), latest=r.latest)

    def _command(self, cmd: CommandIn, now: float, executed: int) -> int:
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
            self._cmd_counts["unrecorded"] += 1
            self._refuse(now, what, src, "UNRECORDED")
            self.adapter.ack(cmd, mavlink.MAV_RESULT_DENIED, Reason.UNRECORDED, opcode, now)
            return 0
        if executed >= self.cfg.commands_per_frame:
            self._cmd_counts["busy"] += 1
            self._refuse(now, what, src, "BUSY")
            self.adapter.ack(cmd, mavlink.MAV_RESULT_TEMPORARILY_REJECTED, Reason.BUSY, opcode, now)
            return 0
        self._seq += 1
        self._dictionary(cmd, opcode, src)
        return 1

    def _dictionary(self, cmd: CommandIn, opcode: int, src: str) -> None:
        p1 = cmd.param1
        commands = self.ctx.commands
        name = commands.name_of(opcode) if opcode else None
        if name is None:  # let the dispatcher refuse it, so counters and events stay uniform
            commands.dispatch(CommandRequest(f"opcode {p1!r}", {}, self._seq, f"mavlink:{src}"))
            self._cmd_counts["refused"] += 1
            self.adapter.ack(cmd, mavlink.MAV_RESULT_DENIED, Reason.UNKNOWN_OPCODE, opcode)
            return
        try:
            args = decode_args(commands.definitions()[name][1], cmd.params)
        except ValueError as exc:
            self.event("CMD_BAD_ARGS", command=name, reason=str(exc))
            self._cmd_counts["refused"] += 1
            self.adapter.ack(cmd, mavlink.MAV_RESULT_DENIED, Reason.BAD_ARGUMENTS, opcode)
            return
        resp = commands.dispatch(CommandRequest(name, args, self._seq, f"mavlink:{src}"))
        ok = resp.status is CommandStatus.OK
        self._cmd_counts["accepted" if ok else "refused"] += 1
        reason = Reason.VALIDATION if resp.status is CommandStatus.VALIDATION_ERROR else Reason.NONE
        self.adapter.ack(cmd, RESULT_OF_STATUS[resp.status], reason, opcode)

    def _request(self, req: GcsRequest, now: float) -> None:
        src = f"{req.src_system}/{req.src_component}"
        if req.verdict is not None and req.verdict is not Verdict.OK:
            self._refuse(now, "PARAM_SET", src, req.verdict.value)
        recorded = req.verdict is Verdict.OK and self.journal.covers(req.stream, req.timestamp)
        text = self.gcs.request(req, now, recorded)
        if text is not None:
            self.event("PARAM_SET_REFUSED" if "refused" in text else "PARAM_SET", text=text)
