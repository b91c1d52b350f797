"""Agents: one flight program of the team, as a topology over the same framework and executive.

An agent is what one flight computer runs: its tasks and rate groups (the ``[executive]``
schedule), the configuration sections it reads, the component ids the topology gives its
components, and its MAVLink system id (``[mavlink] system_id``). The RECON-bot is agent kind
``recon``; a second agent (the Cliff-bot) is a new :class:`AgentTopology` and its tasks,
never a copy of the executive. The ``[agent]`` section of a configuration names the agent
and its kind; the kind picks the topology (``fsw.registry.AGENTS``): which task kinds
its schedule may use and which sections its file may set. docs/architecture.md, "Agents".
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from fsw.framework.params import param


@dataclass(frozen=True)
class AgentConfig:
    """``[agent]``: which agent this configuration is."""

    name: str = param("recon-1", doc="the agent's name (events, logs, the bench's agent list)")
    kind: str = param("recon", doc="the agent's topology (fsw.registry.AGENTS): recon = the RECON-bot, "
                      "cliffbot = the Cliff-bot")

    def __post_init__(self) -> None:
        if not self.name or not self.name.replace("-", "").replace("_", "").isalnum():
            raise ValueError(f"agent name {self.name!r}: letters, digits, '-' and '_' only")


@dataclass(frozen=True)
class AgentTopology:
    """One kind of agent: the task kinds it may schedule and the sections its configuration may
    set (besides ``[agent]`` and ``[executive]``, which every agent has)."""

    kind: str
    doc: str
    task_kinds: Mapping[str, str]  # task kind -> "module:Class", imported when the schedule names it
    sections: frozenset[str] = field(default_factory=frozenset)
    required_tasks: tuple[str, ...] = ()  # task kinds its schedule must contain
    flight_kinds: tuple[str, ...] | None = None  # a flight file's must-have kinds (None: schedule_check.FLIGHT_KINDS)

    def check_sections(self, present: set[str]) -> None:
        """``ValueError`` naming a configuration section this agent does not read."""
        extra = sorted(present - self.sections - {"agent", "executive"})
        if extra:
            raise ValueError(f"agent kind {self.kind!r} reads no [{extra[0]}] section "
                             f"(it reads: {', '.join(sorted(self.sections)) or 'none beyond [executive]'})")

    def check_tasks(self, kinds: list[str]) -> None:
        """``ValueError`` naming a task kind the schedule lacks or this agent does not have."""
        for k in kinds:
            if k not in self.task_kinds:
                raise ValueError(f"unknown task kind {k!r} for agent kind {self.kind!r} "
                                 f"(known: {', '.join(sorted(self.task_kinds))})")
        missing = [k for k in self.required_tasks if k not in kinds]
        if missing:
            raise ValueError(f"agent kind {self.kind!r} needs a task of kind {missing[0]!r} in [executive] tasks")
