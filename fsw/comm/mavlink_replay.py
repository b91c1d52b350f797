"""What the replay window has on non-volatile storage: a high-water mark per signed stream, reserved ahead.

Replay protection across a restart needs every timestamp a command executed with to be on
disk *before* the command acts (otherwise a crash between the two forgets it, and the
recorded frame runs again after the restart). Writing the window for every command costs
one fsync per command (a signed flood of 300 commands a second then starved the executive).
Instead the window on disk holds, per stream ``(link_id, system, component)``, a mark
``reserve`` ahead of the newest timestamp accepted when it was written: commands whose
timestamp is at or below the mark are already covered, so a ground station whose clock runs
in real time costs one write per ``reserve`` (``[mavlink] signing_reserve_s``), whatever its
command rate, and at most one write per activation in any case.

After a restart the marks are the window: a command at or below a mark is a REPLAY, so a
ground station's own commands are refused for at most ``signing_reserve_s`` after the last
one accepted before the restart (a restart takes longer than that).

Sans-I/O: :meth:`ReplayJournal.plan` says what to write; the owner writes it
(``fsw.drivers.signing_store``) and calls :meth:`ReplayJournal.written` only on success. A
command whose timestamp is not covered (:meth:`ReplayJournal.covers`) must not execute.
"""

from __future__ import annotations

from dataclasses import dataclass, field

Stream = tuple[int, int, int]
TS_PER_S = 100_000  # signing timestamps count 10 us units


@dataclass
class ReplayJournal:
    reserve: int  # signing time units written ahead of the newest accepted timestamp
    max_streams: int = 64
    recorded: dict[Stream, int] = field(default_factory=dict)  # what the file on disk holds
    writes: int = 0

    def restore(self, streams: dict[Stream, int]) -> None:
        """The window read at start-up is what the disk holds."""
        self.recorded = dict(streams)

    def covers(self, stream: Stream, ts: int) -> bool:
        """True when a command of ``stream`` at ``ts`` may act: its timestamp is on disk."""
        return ts <= self.recorded.get(stream, -1)

    def plan(self, accepted: dict[Stream, int]) -> dict[Stream, int] | None:
        """The window to write so that every accepted timestamp is covered (None: nothing to
        write). Streams already covered keep their marks; the others get ``ts + reserve``."""
        need = {s: ts for s, ts in accepted.items() if ts > self.recorded.get(s, -1)}
        if not need:
            return None
        out = dict(self.recorded)
        for s, ts in need.items():
            out[s] = ts + self.reserve
        if len(out) > self.max_streams:  # bounded: the streams quiet longest (lowest marks) go
            keep = sorted(out, key=out.__getitem__, reverse=True)[:self.max_streams]
            out = {s: out[s] for s in keep}
        return out

    def written(self, window: dict[Stream, int]) -> None:
        self.recorded = dict(window)
        self.writes += 1
