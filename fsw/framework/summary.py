"""Rate-limited summaries: many occurrences of one kind, one event per period with their count.

Routine noise (timing overruns and slips, commands refused during a flood) is counted
exactly in telemetry channels; what reaches the event log is one summary per ``period_s`` at
most: the first occurrence after a quiet period is reported at once (something changed), the
ones after it are added up and reported when the period has passed (as F Prime's
throttled events; docs/ground.md, "Events").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Report:
    count: int  # occurrences since the last report
    by_key: dict[str, int]
    latest: str  # what the newest occurrence said
    span_s: float  # time the count covers

    def top(self, n: int = 3) -> str:
        """``"a 5, b 2"``: the keys with the most occurrences."""
        ranked = sorted(self.by_key.items(), key=lambda kv: (-kv[1], kv[0]))[:n]
        more = len(self.by_key) - len(ranked)
        return ", ".join(f"{k} {v}" for k, v in ranked) + (f", +{more} more" if more > 0 else "")


@dataclass
class Summary:
    period_s: float
    total: int = 0
    pending: int = 0
    by_key: dict[str, int] = field(default_factory=dict)
    latest: str = ""
    last_report_s: float = -math.inf
    first_pending_s: float = 0.0

    def note(self, now_s: float, key: str, detail: str = "", n: int = 1) -> None:
        if not self.pending:
            self.first_pending_s = now_s
        self.total += n
        self.pending += n
        self.by_key[key] = self.by_key.get(key, 0) + n
        self.latest = detail or key

    def report(self, now_s: float) -> Report | None:
        """A report when something is pending and the last one is ``period_s`` old, else None."""
        if not self.pending or now_s - self.last_report_s < self.period_s - 1e-9:
            return None
        since = self.first_pending_s if math.isinf(self.last_report_s) else self.last_report_s
        out = Report(self.pending, dict(self.by_key), self.latest, max(0.0, now_s - since))
        self.pending, self.by_key, self.last_report_s = 0, {}, now_s
        return out
